"""The saddle between two minima of problem (6) at one Q: a mountain pass over one pinned vertex.

Pin one free vertex x⋆ at a point z (problem (6) with one more handle) and let E⋆(z) be the energy of the pinned
minimum. Its gradient is the **reaction force** f(z) = ∂E/∂X_{x⋆} at that minimum (the unpinned gradient read at
the pinned vertex: every other free vertex is in equilibrium), so f = 0 exactly where the pinned minimum is a
critical point of problem (6) itself. The pass from a minimum X_a to X_b is followed as a **profile**: the height
z_y of x⋆ steps from X_a's towards X_b's, z_x relaxes to f_x = 0 (a secant on the reaction force, each pinned solve
warm-started from the last) and the energy climbs. Where f_y changes sign the profile has its maximum; a secant on
f_y refines it to a critical point of problem (6): the saddle. The family ends where the pinned minimum folds (the
energy drops to the other basin); each end gives its own saddle.

Eq. (11) has a kink on conformal Jacobians, so "critical" and "index" are read on the held problem: the S-ARAP
triangles on the kink keep their anti-conformal part (the solver's held modes, :func:`held_constraints`). Along a
direction that keeps it, the energy is smooth; along any other, the cone r‖a‖ makes it rise linearly first.
:func:`probe` measures E(X + tD) − E(X) over a log range of t for both. Pure computation; drawing is in
:mod:`defop.view.branches`.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .. import options as opt
from ..variational.escape import negative_curvature
from ..variational.newton import step_off
from ..variational.solver import NotConvergedWarning, Solver
from ..variational.verify import KINK, held_on_kink, inertia_shift

__all__ = [
    "Profile",
    "Saddle",
    "descents",
    "held_constraints",
    "held_curvature",
    "inertia",
    "mountain_pass",
    "pinned_minimum",
    "probe",
    "profile",
    "refine_saddle",
    "relax",
    "smooth_direction",
]


@dataclasses.dataclass
class Profile:
    """The pinned minima along a pass: per step the pin (k, 2), E⋆ (k,), reaction force (k, 2), X (k, n, 2).

    ``converged`` (k,) says whether each pinned solve verified; ``top`` is the step before the one where f_y turned
    against the climb (the maximum of E⋆ lies between them), None when the profile ended without one (at its end
    height or at a fold).
    """

    pins: np.ndarray
    energies: np.ndarray
    forces: np.ndarray
    X: np.ndarray
    converged: np.ndarray
    top: int | None


@dataclasses.dataclass
class Saddle:
    """A critical point of problem (6) found by :func:`refine_saddle`.

    ``force`` is the reaction force (2,) at the pin, ``force_scale`` the largest along the profile it was found
    on; ``negative`` the negative pivots of the exact held Hessian, unshifted, and ``negative_shifted`` with check
    5's shift (what ``verify`` sees); ``curvature`` its most negative eigenvalue (:func:`held_curvature`);
    ``converged`` whether the last pinned solve verified (a pinned minimum; ``verified`` is problem (6)'s check).
    """

    X: np.ndarray
    energy: float
    pin: np.ndarray
    force: np.ndarray
    force_scale: float
    negative: int
    negative_shifted: int
    curvature: float
    verified: bool
    reason: str
    converged: bool = True


def check_pass_input(solver, vertex, X=(), name="X0"):
    """``vertex`` as a free vertex index of a triangle mesh and each X as a finite (n, 2) array, or a ValueError.

    The mountain pass reads the anti-conformal part of triangle Jacobians (:func:`held_constraints`): 2D only.
    """
    if solver.dim != 2:
        raise ValueError(
            f"the mountain pass is written for triangle meshes (d = 2; S-ARAP's kink there), got d = {solver.dim}"
        )
    n = solver.mesh.n_vertices
    vertex = opt.integer("vertex", vertex, minimum=0, maximum=n - 1)
    if vertex in set(solver.handles.tolist()):
        raise ValueError(f"vertex must be a free vertex, got handle {vertex}")
    return vertex, [opt.points(name, Y, n=n, d=2) for Y in X]


def pinned_minimum(pinned, solver, targets, vertex, z, X0):
    """The minimum of problem (6) with ``vertex`` pinned at z, warm-started at X0, and its reaction force.

    Parameters
    ----------
    pinned : Solver
        The solver with ``vertex`` appended to the handles (last).
    solver : Solver
        The unpinned solver (its gradient gives the reaction force).
    targets : (h, 2) numpy array
        The unpinned solver's handle targets.
    vertex : int
    z : (2,) numpy array
    X0 : (n, 2) numpy array

    Returns
    -------
    X : (n, 2) numpy array
    energy : float
    force : (2,) numpy array
        ∂E/∂X at the pinned vertex (= ∇E⋆(z)).
    converged : bool
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        r = pinned.solve(np.vstack([targets, z]), X0=X0)
    g = solver.grad_hess(r.X, 0.0, project=False)[1].reshape(-1, solver.dim)
    return np.asarray(r.X), float(r.energy), g[vertex].copy(), bool(r.converged)


def _secant(f, a, b, fa, fb, tol, max_iter, cap):
    """Root of the scalar part of ``f`` by the secant method from a, b (steps capped at ``cap``; stops at |f| ≤ tol
    or once the step is below 1e-6 of the cap, where the solver's noise in f dominates).

    Returns
    -------
    b : float
    fb : numpy array
    slope : float
        The last secant slope (nan if none).
    """
    slope = np.nan
    for _ in range(max_iter):
        if abs(fb[0]) <= tol or fb[0] == fa[0] or abs(b - a) < 1e-6 * cap:
            break
        slope = (fb[0] - fa[0]) / (b - a)
        c = float(np.clip(b - fb[0] / slope, b - cap, b + cap))
        a, fa, b, fb = b, fb, c, f(c)
    return b, fb, slope


def relax(pinned, solver, targets, vertex, y, X0, x0, tol=1e-6, max_iter=20, state=None):
    """E⋆ minimised over the pin's x at height y: a secant on f_x = ∂E⋆/∂x (each solve warm-started).

    ``state`` (a dict, optional) carries the secant's slope ∂f_x/∂x from one call to the next: along a profile it
    changes slowly, so the first step is nearly a Newton step.

    Returns
    -------
    z : (2,) numpy array
    X, energy, force, converged
        As :func:`pinned_minimum` at z.
    """
    memo, state = {}, {} if state is None else state

    def f(x):
        prev = memo.get("last", (None, X0))[1]
        X, E, F, ok = pinned_minimum(pinned, solver, targets, vertex, [x, y], prev)
        memo["last"] = (x, X)
        memo[x] = (X, E, F, ok)
        return F

    fa = f(x0)
    cap = 0.05 * solver.mesh.bbox_diagonal
    k = state.get("slope", np.nan)
    x1 = x0 + 1e-3 * solver.mesh.bbox_diagonal if not np.isfinite(k) or k <= 0 else x0 - fa[0] / k
    x1 = float(np.clip(x1, x0 - cap, x0 + cap))
    if abs(fa[0]) <= tol:
        x = x0
    else:
        x, _, k = _secant(f, x0, x1, fa, f(x1), tol, max_iter, cap)
        if np.isfinite(k):
            state["slope"] = k
    X, E, F, ok = memo[x]
    return np.array([x, y]), X, E, F, ok


def profile(solver, targets, vertex, X0, y_end, steps, halvings=6, tol=1e-5):
    """The pinned minima from X0 towards height ``y_end`` of ``vertex`` (each relaxed in x), up to the first top.

    Steps of (y_end − y₀)/steps, each warm-started from the last. A step is kept when its energy is the integral of
    the reaction force (E⋆ has gradient f: the trapezoid rule ΔE ≈ (f_y + f_y')Δy/2 holds to 10% of |ΔE| plus
    1e-3 of the energy scale); otherwise the pinned minimum has left the family (folded into the other basin) and
    the step is halved, up to ``halvings`` times. The profile stops after the first step where f_y changes sign
    (the maximum of E⋆ along the family: :func:`refine_saddle` takes it from there), at y_end, or at a fold.

    Parameters
    ----------
    solver : Solver
        Unpinned, S-ARAP or any energy.
    targets : (h, 2) numpy array
    vertex : int
        A free vertex.
    X0 : (n, 2) numpy array
        The start (a minimum of problem (6)).
    y_end : float
    steps : int
    halvings : int
    tol : float
        |f_x| at which a step's x is relaxed (the climb needs less than the top: :func:`refine_saddle`).

    Returns
    -------
    Profile
    """
    vertex, (X0,) = check_pass_input(solver, vertex, [X0])
    steps = opt.integer("steps", steps, minimum=1)
    halvings = opt.integer("halvings", halvings, minimum=0, maximum=30)
    if not (isinstance(y_end, (int, float, np.floating, np.integer)) and np.isfinite(y_end)):
        raise ValueError(f"y_end must be a finite height, got {y_end!r}")
    if float(y_end) == X0[vertex, 1]:
        raise ValueError(f"y_end must differ from the start's height {X0[vertex, 1]!r}")
    pinned = Solver(solver.mesh, np.append(solver.handles_given, vertex), solver.energy)
    X = X0
    state = {}
    z, X, E, F, ok = relax(
        pinned, solver, targets, vertex, float(X[vertex, 1]), X, float(X[vertex, 0]), tol, state=state
    )
    rows, h = [(z, E, F, X, ok)], (y_end - z[1]) / steps
    scale = 1e-3 * solver.scale(E)
    while (y_end - z[1]) * np.sign(h) > 1e-12 and abs(h) > abs(y_end - X0[vertex, 1]) / steps / 2**halvings:
        y = z[1] + h if abs(y_end - z[1]) > abs(h) * 1.000001 else y_end
        z1, X1, E1, F1, ok1 = relax(pinned, solver, targets, vertex, y, X, z[0], tol, state=state)
        dE = E1 - E
        if abs(dE - (F[1] + F1[1]) * (y - z[1]) / 2) > 0.1 * abs(dE) + scale:
            h /= 2  # left the family: smaller step
            continue
        z, X, E, F, ok = z1, X1, E1, F1, ok1
        rows.append((z, E, F, X, ok))
        if len(rows) > 2 and F[1] * h < 0:  # the first step leaves a minimum, where f ≈ 0 has no sign
            break
    pins, E, F, Xs, ok = (np.array(c) for c in zip(*rows))
    top = len(rows) - 2 if len(rows) > 2 and F[-1, 1] * h < 0 else None
    return Profile(pins, E, F, Xs, ok, top)


def refine_saddle(solver, targets, vertex, prof, tol=1e-7, max_iter=12):
    """The critical point at the top of a profile: a secant on f_y between the steps around its sign change.

    Returns
    -------
    Saddle or None
        None when f_y does not change sign along the profile (no top found).
    """
    i = prof.top
    if i is None:
        return None
    pinned = Solver(solver.mesh, np.append(solver.handles_given, vertex), solver.energy)
    memo, state = {"X": prof.X[i], "x": prof.pins[i, 0]}, {}

    def f(y):
        z, X, E, F, ok = relax(pinned, solver, targets, vertex, y, memo["X"], memo["x"], tol, state=state)
        memo.update(X=X, x=z[0], z=z, E=E, F=F, ok=ok)
        return F[::-1]  # secant on f_y

    ya, yb = prof.pins[i, 1], prof.pins[i + 1, 1]
    fa = f(ya)
    _secant(f, ya, yb, fa, f(yb), tol, max_iter, abs(yb - ya))
    X, T = memo["X"], solver.targets_of(targets)
    neg, neg_shift = inertia(solver, X)
    check = solver.verify(X, T)
    scale = float(np.linalg.norm(prof.forces, axis=1).max())
    curv = held_curvature(solver, X)[0]
    return Saddle(X, memo["E"], memo["z"], memo["F"], scale, neg, neg_shift, curv, check.ok, check.reason, memo["ok"])


def mountain_pass(solver, targets, vertex, Xa, Xb, steps=12):
    """Both ends' profiles from X_a towards X_b and back, and the saddle at the top of each.

    Parameters
    ----------
    solver : Solver
    targets : (h, 2) numpy array
    vertex : int
        The pinned vertex (e.g. the mid-bar point).
    Xa, Xb : (n, 2) numpy arrays
        Two minima of problem (6) at these targets.
    steps : int
        Steps of a profile from one minimum's height of ``vertex`` to the other's (:func:`profile` halves them
        where the pinned minimum folds).

    Returns
    -------
    profiles : tuple of two Profile
        From X_a and from X_b.
    saddles : tuple of two Saddle or None
    """
    vertex, (Xa, Xb) = check_pass_input(solver, vertex, [Xa, Xb], "Xa and Xb")
    steps = opt.integer("steps", steps, minimum=3)
    ya, yb = float(Xa[vertex, 1]), float(Xb[vertex, 1])
    if abs(ya - yb) < 1e-9 * solver.mesh.bbox_diagonal:
        raise ValueError("Xa and Xb must put vertex at different heights")
    pa = profile(solver, targets, vertex, Xa, yb, steps)
    pb = profile(solver, targets, vertex, Xb, ya, steps)
    return (pa, pb), tuple(refine_saddle(solver, targets, vertex, p) for p in (pa, pb))


def inertia(solver, X):
    """Negative pivots of the exact held Hessian at X (as check 5 assembles it): unshifted, and with check 5's shift.

    Check 5 shifts the diagonal (:func:`defop.variational.verify.inertia_shift`) so that round-off does not count;
    a shift taken from the mean |diagonal| hid the bar's saddle: the held triangles' stiff modes make that mean
    2.6e7 against a median of 8.8.

    Returns
    -------
    negative, negative_shifted : int
    """
    _, g, data, _ = solver.grad_hess(X, 0.0, project=False, kink=KINK)
    out = []
    for shift in (0.0, inertia_shift(solver, data)):
        solver.newton_direction(g[solver.free], data, rel_shift=shift)
        out.append(solver.hessian.inertia())
    return tuple(out)


def held_constraints(solver, X):
    """The anti-conformal Jacobian part of each S-ARAP triangle held on Eq. (11)'s kink, as rows on the free dofs.

    J = [[p, q], [r, s]] has anti-conformal part ((p − s)/2, (q + r)/2); Σ = σ exactly when it is 0 (det J > 0).

    Returns
    -------
    C : (2k, n_free) scipy sparse matrix
        For the k held triangles (:func:`defop.variational.verify.held_on_kink` with ``KINK``); empty if none.
    """
    if solver.dim != 2:
        raise ValueError(f"held_constraints reads triangle Jacobians (d = 2), got d = {solver.dim}")
    held = held_on_kink(solver, X, KINK)[3]
    G = solver.mesh.jacobian_operator.tocsr()
    t = np.flatnonzero(held)
    A = sp.csr_matrix(
        (np.tile([0.5, -0.5, 0.5, 0.5], len(t)), (np.repeat(np.arange(2 * len(t)), 2), _anti_rows(t))),
        shape=(2 * len(t), G.shape[0]),
    )
    return (A @ G)[:, solver.free].tocsr()


def _anti_rows(t):
    """Rows of the Jacobian operator: (J00, J11) and (J01, J10) of each triangle t."""
    return np.stack([4 * t, 4 * t + 3, 4 * t + 1, 4 * t + 2], axis=1).ravel()


def held_curvature(solver, X):
    """The most negative curvature of problem (6) at X with the kink-held offsets kept (their modes stiff).

    Shift-invert Lanczos on the exact held Hessian: the eigenvalue nearest −median|diag| (below each negative one at
    the bar's saddles, so there the most negative; not guaranteed in general), then the eigenvector projected
    exactly onto {held anti-conformal parts unchanged} (:func:`held_constraints`).

    Returns
    -------
    lam : float
        The eigenvalue of the held Hessian (its stiff modes are ~1e5 × the others).
    D : (n, 2) numpy array
        Unit (max-norm) direction, zero at the handles, that keeps every held triangle's offset.
    """
    K = solver.hessian.full(solver.grad_hess(X, 0.0, project=False, kink=KINK)[2])
    sigma = -float(np.median(np.abs(K.diagonal())))
    v0 = np.ones(K.shape[0])
    lam, v = sla.eigsh(K, k=1, sigma=sigma, which="LM", v0=v0)
    u = v[:, 0]
    C = held_constraints(solver, X)
    if C.shape[0]:
        Cd = C.toarray()
        u = u - Cd.T @ np.linalg.lstsq(Cd @ Cd.T, Cd @ u, rcond=None)[0]
    D = solver.full(u)
    return float(lam[0]), D / np.abs(D).max()


def probe(solver, X, D, ts):
    """E(X ± tD) − E(X) for each t (both signs).

    Parameters
    ----------
    solver : Solver
    X, D : (n, 2) numpy arrays
        D zero at the handles.
    ts : (k,) numpy array

    Returns
    -------
    dE : (2, k) numpy array
        Row 0 for +t, row 1 for −t.
    """
    E = solver.energy_of(X)
    return np.array([[solver.energy_of(X + s * t * D) - E for t in ts] for s in (1.0, -1.0)])


def smooth_direction(solver, X):
    """The most negative eigenvector of the smooth exact Hessian (no kink held), unit in max-norm, and its value."""
    lam, D = negative_curvature(solver, X)
    return lam, D / np.abs(D).max()


def descents(solver, targets, X, D):
    """Where the two descents from a saddle end: a step off along ±D with lower energy, then a solve from there.

    Parameters
    ----------
    solver : Solver
    targets : (h, 2) numpy array
    X : (n, 2) numpy array
        The saddle.
    D : (n, 2) numpy array
        Its descent direction (:func:`held_curvature`).

    Returns
    -------
    ends : list of two (n, 2) numpy arrays or None
        None where no step along that sign lowers the energy or the solve does not verify.
    """
    ends = []
    for sign in (1.0, -1.0):
        Xs = step_off(solver, X, sign * D)
        if Xs is None:
            ends.append(None)
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotConvergedWarning)
            r = solver.solve(targets, X0=Xs)
        ends.append(np.asarray(r.X) if r.converged else None)
    return ends

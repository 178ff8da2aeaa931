"""The five checks behind ``converged``: a verified local minimum of problem (6).

At the returned X, with the handles written onto their targets: (1) the energy is finite; (2) every handle sits
on its target to ``HANDLE_TOL`` of the bounding-box diagonal; (3) for barrier energies, no element is flipped or
collapsed; (4) the Newton decrement of the true energy (Eq. 10 / 11, μ = 0; at S-ARAP's kink, its conformal
part) is small, and the S-ARAP triangles held on the kink are in equilibrium on its cone up to ``verify_tol`` · E: a
Fenchel bound on what their offsets and any pull beyond the cone cost (:func:`kink_pull`,
:func:`defop.variational.kink.fenchel_gap`), or, where that bound is loose, a smoothed solve from X
(:func:`defop.variational.kink.smoothing_certificate`); (5) the exact reduced Hessian has no negative
eigenvalue (beyond an ``INERTIA_SHIFT`` relative shift of the median diagonal, the one policy of
:func:`defop.variational.inertia.inertia_shift`), read from the inertia of its LDLᵀ factorisation (Sylvester's law:
the signs of D). :class:`Verification` names the check that failed.

The held set's pieces (:func:`~defop.variational.kink.held_on_kink`, :func:`~defop.variational.kink.kink_pull`,
:func:`~defop.variational.kink.kink_gap`) live in :mod:`defop.variational.kink`, below :mod:`.newton`, which uses them
too; this module imports :mod:`.newton` (the certificate's smoothed stage), never the other way round.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..geometry.mesh import ELEMENT
from . import kink
from .inertia import INERTIA_SHIFT, ROUNDOFF, inertia_shift
from .kink import held_on_kink, kink_gap, kink_pull
from .newton import Log, newton_stage
from .problem import count_flips

#: names whose home is :mod:`.kink` or :mod:`.inertia`, kept importable from here
__all__ = [
    "CERTIFICATE_ITERATIONS",
    "HANDLE_TOL",
    "INERTIA_SHIFT",
    "KINK",
    "ROUNDOFF",
    "Verification",
    "held_on_kink",
    "inertia_shift",
    "kink_gap",
    "kink_pull",
    "verify_point",
]

#: handles must sit on their targets to this fraction of the bounding-box diagonal (check 2)
HANDLE_TOL = 1e-12
#: S-ARAP triangles with Σ − σ ≤ KINK · Σ sit on Eq. (11)'s kink for check 4
#: (:func:`defop.variational.planar.eigensystem`)
KINK = 1e-4
#: iteration budget of the smoothed solve behind check 4's smoothing certificate
#: (:func:`defop.variational.kink.smoothing_certificate`)
CERTIFICATE_ITERATIONS = 50


@dataclasses.dataclass
class Verification:
    """Outcome of :func:`verify_point`: ``ok``, the first failed check (``failed``, "" if none) and why."""

    ok: bool
    failed: str
    reason: str
    energy: float
    decrement: float = np.nan
    negative: int = 0
    #: check "kink" only: the (n, d) direction that pulls the overloaded triangles off Eq. (11)'s kink
    kink: np.ndarray | None = dataclasses.field(default=None, repr=False)


def verify_point(solver, X, T, tol=None):
    """The five checks behind ``converged``, at X (handles already on their targets).

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    X : (n, d) numpy array
    T : (u, d) numpy array
        Targets per unique handle (:meth:`~defop.variational.problem.ReducedProblem.targets_of`).
    tol : float, optional
        Check 4's tolerance (default ``solver.verify_tol``).

    Returns
    -------
    check : Verification
        ``failed`` is one of "energy", "handles", "flips", "saddle", "decrement", "kink" (or "").
    """
    tol = solver.verify_tol if tol is None else tol
    mesh = solver.mesh
    E = solver.energy_of(X)
    flips = count_flips(mesh, X)
    el = ELEMENT[mesh.dim]
    if not np.isfinite(E):
        return Verification(False, "energy", f"energy is not finite (E = {E}, {flips} flipped/collapsed {el}(s))", E)
    err = float(np.abs(X[solver.handles] - T).max()) / mesh.bbox_diagonal
    if not err <= HANDLE_TOL:
        return Verification(False, "handles", f"a handle is {err:.2e} of the diagonal off its target", E)
    if solver.barrier and flips:
        return Verification(False, "flips", f"{flips} flipped or collapsed {el}(s)", E)
    E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=solver.kink_threshold)  # true E, exact Hessian
    gf = g[solver.free]
    p = solver.newton_direction(gf, data, rel_shift=inertia_shift(solver, data))
    negative = solver.hessian.inertia()
    dec = -float(gf @ p) / 2
    if negative:
        why = f"saddle point: the reduced Hessian has {negative} negative eigenvalue(s)"
        return Verification(False, "saddle", why, E, dec, negative)
    if not (np.isfinite(dec) and dec <= tol * solver.scale(E)):
        why = f"the true energy's Newton decrement λ²/2 = {dec:.2e} > {tol:g}·E"
        return Verification(False, "decrement", why, E, dec)
    if solver.energy == "sarap":
        gain, worst, D, _, offset = kink_pull(solver, X, local, p, solver.kink_threshold)
        bound = gain + offset
        if bound > tol * solver.scale(E):
            cert = kink.smoothing_certificate(
                lambda Y, m, t: _certificate_stage(solver, Y, t, m),
                lambda Y, m: kink.newton_decrement(solver, Y, m),
                X,
                E,
                kink.certificate_mu(E, mesh.areas.sum(), tol),
                tol,
            )
            if cert > tol * solver.scale(E):
                why = (
                    "not a minimum at Eq. (11)'s kink: "
                    + (
                        f"{el} {worst[0]} is pulled off it by {worst[1]:.4g} times the force its cone bears; "
                        if worst
                        else "the held elements' offsets from it cost "
                    )
                    + f"up to {bound:.2e} > {tol:g}·E (smoothing bound {cert:.2e})"
                )
                return Verification(False, "kink", why, E, dec, 0, D)
    return Verification(True, "", "", E, dec, 0)


def _certificate_stage(solver, X, tol, mu):
    """One smoothed Newton stage on a fresh iteration budget (for :func:`.kink.smoothing_certificate`)."""
    return newton_stage(solver, Log(CERTIFICATE_ITERATIONS), X, tol, mu)

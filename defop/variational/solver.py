"""The variational DefOp D^E: minimise a deformation energy subject to point-handle constraints.

Problem (6) of the paper: min_X E(X) = Σ_t A_t ψ(J_t(X)) subject to X[handles] = targets, over
piecewise-linear maps X (n, d). :class:`Solver` is the facade: it holds the reduced problem
(:class:`defop.variational.problem.ReducedProblem`: handles eliminated, the Hessian's fixed sparsity pattern and
its LDLᵀ) as ``problem``, reads its attributes through (``mesh``, ``free``, ``grad_hess``...), and adds the settings
of the solve, which runs

* continuation and projected Newton with its line search (:mod:`defop.variational.newton`);
* the five checks behind ``converged``, a **verified local minimum** (:mod:`defop.variational.verify`): a finite
  energy, handles on their targets, no flipped element for barrier energies, a small true decrement (and S-ARAP's
  kink in equilibrium), no negative eigenvalue of the exact reduced Hessian; ``reason`` names the check that
  failed;
* escapes from saddles and from S-ARAP's kink (:mod:`defop.variational.escape`).

Starts: any flip-free map can warm-start a local solve (``X0``); its handles need not be at the targets.
:meth:`Solver.solve_best` is the one multi-start policy: local solves from several starts (the rest pose, a
bootstrap prediction, a previous solution), keeping the lowest verified minimum; ``solve(..., start="global")``
uses it. Baselines on the same energies are in :mod:`defop.variational.baselines`.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from .. import options as opt
from .checks import check_handle_span, check_handles, check_max_iter, check_tol, count_flips
from .escape import escape
from .newton import Log, continuation
from .problem import ReducedProblem
from .verify import KINK, verify_point

#: bumped whenever a change to the solver moves its solutions (cache keys of ground truth should include it)
VERSION = 6  # 6: the escape's direction above 400 unknowns by shift-invert Lanczos (escape.negative_curvature)
# 5: check 5 shifts by the median diagonal (a saddle on the kink was accepted as a minimum)
# not bumped when the kink code took check 5's shift too: no minimum moved by more than 5.3e-16 of E or
# 5.5e-13 of the diagonal on 889 samples (aleph, bar, U, Fig. 10's grid; benchmarks/bench_inertia_shift.py)


#: S-ARAP's default smoothing stages (μ) on triangles, before the final μ = 0 stage
SMOOTHING = (1e-5,)
#: ... and on tetrahedra: none, the μ = 0 stage with its held kink set at once. Measured against ``(1e-5,)``:
#: bar_3d, 30 samples from the rest pose, 14% less CPU, 30/30 verified, 3 minima moved by at most 7e-9 relative
#: (``bench_newton_policy.py --shape bar_3d --samples 30 --seed 2``); octopus_3d in benchmarks/README.md
SMOOTHING_3D = (0.0,)
#: ... within this many Newton iterations per continuation stage; else the 2D schedule runs from the same point (a
#: pinned box scaled by 0.7, every tetrahedron on the triple point σ₁ = σ₂ = σ₃, spent 300 iterations without it)
HELD_FIRST_ITERATIONS = 30


class NotConvergedWarning(RuntimeWarning):
    """A solve stopped before reaching a verified local minimum."""


def _not_converged(message):
    """Warn ``message`` as a :class:`NotConvergedWarning` at the user's line (:func:`defop.options.user_stacklevel`)."""
    warnings.warn(message, NotConvergedWarning, stacklevel=opt.user_stacklevel())


@dataclasses.dataclass
class SolveResult:
    """Outcome of a solve.

    Attributes
    ----------
    X : (n,2) numpy array
        Deformed positions; ``X[handles] == targets``.
    energy : float
        Final E(X) (the true energy, Eq. 10 / 11).
    energy_history : (k,) numpy array
        E after each iteration (the start first).
    time_history : (k,) numpy array
        Seconds since the start of the solve at each entry of ``energy_history``.
    iterations : int
        Newton (or L-BFGS / local-global) iterations, continuation stages and escapes included.
    time : float
        Wall-clock seconds.
    converged : bool
        X is a verified local minimum (all five checks of :meth:`Solver.verify` pass).
    reason : str
        Why it stopped; when not converged, which check failed.
    flips : int
        Flipped or collapsed triangles in ``X``.
    start : str
        Which start the result came from: ``"X0"``, ``"rest"``, ``"start k"`` (k-th start given to
        :meth:`Solver.solve_best`), followed by ``" > escape +"`` / ``" > escape -"`` for each saddle escape
        and ``" > off kink"`` for each escape from S-ARAP's kink.
    candidates : list of tuple
        (start, energy, converged) of every local minimum or end point the solve reached, escapes and
        other starts included (the result itself is one of them).
    """

    X: np.ndarray
    energy: float
    energy_history: np.ndarray
    time_history: np.ndarray
    iterations: int
    time: float
    converged: bool
    reason: str
    flips: int = 0
    start: str = ""
    candidates: list = dataclasses.field(default_factory=list)


def _joined(first, again):
    """The result of ``again``, a solve run after ``first`` from the same start, counting both: iterations, time, the
    histories (``again``'s times shifted by ``first.time``) and the candidates."""
    return dataclasses.replace(
        again,
        iterations=first.iterations + again.iterations,
        time=first.time + again.time,
        energy_history=np.concatenate([first.energy_history, again.energy_history]),
        time_history=np.concatenate([first.time_history, first.time + again.time_history]),
        candidates=list(first.candidates) + list(again.candidates),
    )


def _held(name, doc, settable=False):
    """An attribute of the solver that is its held problem's ``name`` (read-only unless ``settable``)."""
    fset = (lambda self, value: setattr(self.problem, name, value)) if settable else None
    return property(lambda self: getattr(self.problem, name), fset, doc=doc)


class Solver:
    """Projected-Newton solver of problem (6) on one mesh, one handle set and one energy.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        V (n, d), F (m, d + 1).
    handles : (h,) int numpy array or (n_vertices,) bool numpy array
        Constrained vertices (moving and fixed handles), in any order
        (:func:`defop.variational.problem.check_handles`). Targets are always given in this order. A vertex
        listed twice must get the same target each time. In 3D the handles must not all lie on one line
        (:func:`defop.variational.problem.check_handle_span`: a rotation about it would be free).
    energy : str
        ``"arap"`` (Eq. 10), ``"sarap"`` (Eq. 11), ``"isometric"`` (symmetric Dirichlet), ``"isometric_max"``
        or ``"isometric_exp"`` (see :data:`defop.variational.energies.ENERGIES`).
    tol : float
        Default tolerance: Newton stops at a decrement λ²/2 ≤ tol · E (check 4 uses ``verify_tol``).
    max_iter : int
        Default iteration limit (continuation stages and saddle escapes included).
    smoothing : tuple of float, optional
        S-ARAP only: the μ of the smoothed kink (:func:`defop.variational.planar.psi_sarap_smooth`), one Newton
        stage per entry. A final μ = 0 stage (Eq. 11 itself) is always appended: default ``(1e-5, 0)``. Measured on
        4 problems each on the aleph and the gingerbread man (moves of 5% of the diagonal, against a
        μ → 1e-13 reference), a μ = 1e-5 optimum alone sits up to 3.9e-6 (relative energy) above Eq. (11)'s
        minimum and 3.7e-5 of the diagonal away from it; the default ends within 2.3e-8 of it (0-3 more
        iterations), ``(1e-5, 1e-7, 0)`` within 2e-9 (up to 5 more). The μ = 0 stage treats triangles on the
        kink as check 4 does (below); without that it stalls 2.6e-7 above the minimum. On tetrahedra the default
        is :data:`SMOOTHING_3D` (no smoothed stage): the held μ = 0 stage at once, measured to reach the same
        verified minima with fewer factorisations (benchmarks/README.md, "3D Newton schedule"); where it has not
        converged within :data:`HELD_FIRST_ITERATIONS`, ``(1e-5, 0)`` runs from the same point.
    backend : str, optional
        The factorisation: ``"auto"`` (default, or ``DEFOP_BACKEND``), ``"qdldl"`` or ``"pardiso"`` (MKL, the
        optional ``mkl`` extra); see :func:`defop.variational.problem.choose_backend`. ``hessian.backend`` says which
        one runs. Every back end gives the same minima (tests/test_backend.py).

    Attributes
    ----------
    handles : (u,) int numpy array
        The unique handle vertices, sorted. ``handles_given`` keeps the order of the constructor.
    verify_tol : float
        Check 4: the true energy's Newton decrement λ²/2 ≤ verify_tol · E (default 1e-6; Newton itself stops
        at ``tol``). Eq. (11) is not differentiable on its kink: S-ARAP triangles within ``KINK`` (1e-4,
        relative) of Σ = σ count as sitting on it, with the conformal part of their gradient and stiff
        anti-conformal modes (:func:`defop.variational.planar.eigensystem`, ``kink``); the μ = 0 Newton stage
        uses the same rule, so it stops on this decrement, normally at ``tol``. Without the rule the decrement of
        Eq. (11) stayed up to 1.4e-6 · E (3.4e-5 · E on the bar) at energies converged to 1e-9. A held triangle
        must also be in equilibrium on the cone: check 4 fails ("kink") when the force pulling it off exceeds
        what the cone bears by a bound on the gain above ``verify_tol`` · E (star seed 3273: one triangle pulled at
        1.083 times its cone's force, 1.6e-5 · E above a nearby minimum). The bound also counts what the held
        offsets cost (:func:`defop.variational.kink.fenchel_gap`): a boundary pinned near a uniform scaling
        leaves held triangles up to 2.4e-6 · E above the minimum. Where the held constraints outnumber the free
        dofs their multipliers are not unique and the bound is loose; check 4 then accepts a smoothed solve's
        certificate (:func:`defop.variational.kink.smoothing_certificate`). The solve continues the smoothing
        (μ / 100, :func:`defop.variational.kink.refine`) while the held point's bound exceeds
        ``KINK_TARGET`` · verify_tol · E.

    Notes
    -----
    Newton starts with the PSD-projected Hessian and switches to the exact one once the decrement is
    below ``exact_switch``·E (1e-2) — quadratic instead of linear convergence near the optimum — falling
    back to the projected Hessian whenever the exact direction does not descend or needs a step
    below 1e-3.

    Instances are picklable (for joblib); the factorisation is rebuilt after unpickling. The public attributes
    holding plain values are the solve's settings (:func:`defop.training.cache.solver_settings` keys on them).
    """

    def __init__(self, mesh, handles, energy="sarap", tol=1e-9, max_iter=300, smoothing=None, backend=None):
        check_handle_span(mesh, check_handles(mesh, handles))
        #: the reduced problem this solver minimises (mesh, handles, energy, Hessian pattern and factorisation)
        self.problem = ReducedProblem(mesh, handles, energy, backend)
        #: the energy's name and whether it is a barrier: settings of the solve (a cache key reads them from here)
        self.energy, self.barrier = self.problem.energy, self.problem.barrier
        self.tol = check_tol(tol)
        self.max_iter = check_max_iter(max_iter)
        self.mu_schedule = (0.0,)
        if self.energy == "sarap":
            default = SMOOTHING_3D if mesh.dim == 3 else SMOOTHING
            mus = default if smoothing is None else tuple(check_tol(m, "smoothing μ") for m in smoothing)
            if not mus:
                raise ValueError(f"smoothing must be a non-empty sequence of μ >= 0, got {smoothing!r}")
            self.mu_schedule = mus if mus[-1] == 0 else mus + (0.0,)
            if smoothing is None and mesh.dim == 3:
                #: S-ARAP's default on tetrahedra only (a setting of the solutions there, so an attribute only there,
                #: and 2D's cache keys stay as they were): the schedule that runs from the same point where the held
                #: μ = 0 stage alone has not converged within ``held_first_iterations``
                #: (:func:`defop.variational.newton.newton`) or the solve did not end verified
                self.fallback_schedule = SMOOTHING + (0.0,)
                self.held_first_iterations = HELD_FIRST_ITERATIONS
        self.verify_tol = 1e-6
        #: the μ = 0 stage and check 4 treat S-ARAP triangles within KINK of Σ = σ as on the kink
        self._kink = KINK
        #: switch from the projected to the exact Hessian once λ²/2 ≤ exact_switch · E
        self.exact_switch = 1e-2
        #: tolerance of the intermediate μ stages: from a loosely converged stage, Newton on the next, sharper
        #: kink (curvature ~ 1/μ) crawls with tiny steps (measured: stage tolerance 1e-4 took up to 0.80 s on
        #: the gingerbread man where 1e-8 took 0.08 s)
        self.stage_tol = 1e-8
        #: saddle escapes per solve (each tries both directions)
        self.max_escapes = 4

    mesh = _held("mesh", "The mesh (:class:`defop.geometry.mesh.Mesh`).")
    dim = _held("dim", "d: 2 for triangles, 3 for tetrahedra.")
    handles = _held("handles", "(u,) int numpy array: the unique handle vertices, sorted.")
    handles_given = _held("handles_given", "(h,) int numpy array: the handles in the constructor's order.")
    free_vertices = _held("free_vertices", "(n_free,) int numpy array: the vertices that are not handles.")
    free = _held("free", "(n_free·d,) int numpy array: the free dofs d·v + c, the unknowns.")
    hessian = _held("hessian", "The Hessian's pattern and factorisation (:class:`ReducedHessian`).")
    elements = _held("elements", "The element kernels (:class:`defop.variational.elements.ElementKernels`).")
    scale = _held("scale", ":meth:`ReducedProblem.scale`.")
    targets_of = _held("targets_of", ":meth:`ReducedProblem.targets_of`.")
    jacobians = _held("jacobians", ":meth:`ReducedProblem.jacobians`.")
    energy_of = _held("energy_of", ":meth:`ReducedProblem.energy_of`.")
    energies = _held("energies", ":meth:`ReducedProblem.energies`.")
    grad_hess = _held("grad_hess", ":meth:`ReducedProblem.grad_hess`.")
    newton_direction = _held("newton_direction", ":meth:`ReducedProblem.newton_direction`.")
    full = _held("full", ":meth:`ReducedProblem.full`.")
    extend = _held("extend", ":meth:`ReducedProblem.extend`.")
    check_start = _held("check_start", ":meth:`ReducedProblem.check_start`.")
    kernel = _held("kernel", "The element kernels in use (:attr:`ReducedProblem.kernel`); settable.", settable=True)

    @property
    def kink_threshold(self) -> float:
        """S-ARAP elements within this (relative) of Σ = σ count as on the kink (check 4, the μ = 0 stage)."""
        return self._kink

    def verify(self, X, T, tol=None):
        """The five checks behind ``converged`` at X (n, d), targets T (u, d) per unique handle (:meth:`targets_of`),
        check 4 at ``tol`` (default ``verify_tol``): a :class:`defop.variational.verify.Verification`."""
        return verify_point(self, X, T, tol)

    # ------------------------------------------------------------------ solve
    def solve(self, targets, X0=None, tol=None, max_iter=None, max_stages=64, start="local"):
        """Minimise the energy with the handles at ``targets``; ``converged`` means a verified local minimum.

        Parameters
        ----------
        targets : (h, d) numpy array
            Target positions, one row per entry of ``handles`` given to the constructor (in that order).
        X0 : (n, d) numpy array, optional
            Start (any map; flip-free for a barrier energy). Its handle rows need not be at the
            targets. Default: the rest pose.
        tol : float, optional
            Newton-decrement tolerance relative to the energy (default ``self.tol``).
        max_iter : int, optional
            Iteration limit (default ``self.max_iter``).
        max_stages : int
            Limit on continuation stages for far moves.
        start : {"local", "global"}
            ``"local"``: one path from ``X0`` (warm start, path following; saddles are still escaped).
            ``"global"``: :meth:`solve_best` from the rest pose and ``X0`` (when given), the lower
            verified minimum. This is a documented multi-start, not a certificate: where the energy has
            several minima it can miss a lower one that no start leads to (a test found an
            ARAP bar pushed 0.35 along its axis whose up-bent start verified at 3% lower energy).

        Returns
        -------
        result : SolveResult
            ``converged`` is False (and a :class:`NotConvergedWarning` is issued) when a check of
            :meth:`verify` fails or the iteration limit was hit; ``reason`` says which.

        Raises
        ------
        ValueError
            Targets of the wrong shape, not finite or absurdly far, a vertex with two different
            targets, an invalid ``tol``/``max_iter``, or a flipped start for a barrier energy.
        """
        if start == "global":
            return self.solve_best(targets, starts=() if X0 is None else (X0,), tol=tol, max_iter=max_iter)
        if start != "local":
            raise ValueError(f"start must be 'local' or 'global', got {start!r}")
        result = self._local(targets, X0, tol, max_iter, max_stages, "rest" if X0 is None else "X0")
        if not result.converged:
            _not_converged(f"{self.energy} solve did not converge: {result.reason}")
        return result

    def _local(self, targets, X0, tol, max_iter, max_stages, label):
        """One local solve (continuation, Newton, saddle escapes), verified; no warning. Where 3D's held-first
        schedule does not end verified, the ``fallback_schedule`` solves again from the same start with the iterations
        left of ``max_iter``; the result counts both attempts (:func:`_joined`)."""
        result = self._path(targets, X0, tol, max_iter, max_stages, label)
        left = (self.max_iter if max_iter is None else check_max_iter(max_iter)) - result.iterations
        if result.converged or not getattr(self, "fallback_schedule", None) or left < 1:
            return result  # the fallback shares the solve's iteration budget
        saved = self.mu_schedule, self.fallback_schedule
        self.mu_schedule, self.fallback_schedule = self.fallback_schedule, None
        try:
            again = self._path(targets, X0, tol, left, max_stages, label)
        finally:
            self.mu_schedule, self.fallback_schedule = saved
        return _joined(result, again)

    def _path(self, targets, X0, tol, max_iter, max_stages, label):
        """:meth:`_local` on the solver's schedule."""
        tol = self.tol if tol is None else check_tol(tol)
        log = Log(self.max_iter if max_iter is None else check_max_iter(max_iter))
        T = self.targets_of(targets)
        X = self.check_start(X0)
        self.hessian.forget()
        X, reached, reason, ok = continuation(self, log, X, T, tol, max_stages)
        check = None
        if reached:
            X, label, reason, ok, check = escape(self, log, X, T, tol, label, reason, ok, self.max_escapes)
        else:
            log.candidates.append((label, self.energy_of(X), False))
        return self.finish(log, X, T, reason, label, ok and reached, check)

    def finish(self, log, X, T, reason, label, ok, check=None):
        """The :class:`SolveResult` of a solve ended at X: ``converged`` when ``ok`` and X passes :meth:`verify`."""
        check = self.verify(X, T) if check is None else check
        converged = bool(ok and check.ok)
        if not check.ok:
            reason = f"{reason}; check failed: {check.reason}"
        return SolveResult(
            X=X,
            energy=check.energy,
            energy_history=np.array(log.E),
            time_history=np.array(log.t),
            iterations=log.iters,
            time=time.perf_counter() - log.t0,
            converged=converged,
            reason=reason,
            flips=count_flips(self.mesh, X),
            start=label,
            candidates=list(log.candidates),
        )

    # ------------------------------------------------------------------ the one multi-start policy
    def solve_best(self, targets, starts=(), rest=True, keep="lowest", tol=None, max_iter=None):
        """Local solves from several starts; the lowest-energy verified minimum (the one multi-start policy).

        Every local solve escapes saddles along negative curvature (both directions), so the candidates
        are: each given start, the rest pose (for barrier energies reached through flip-free continuation),
        and the escapes from any saddle on the way.

        Parameters
        ----------
        targets : (h, d) numpy array
            One row per handle given to the constructor.
        starts : sequence of (n, d) numpy arrays or None
            Extra starts (a bootstrap prediction, a previous solution); None entries are ignored, and
            starts that are flipped (barrier energies) or otherwise rejected are skipped.
        rest : bool
            Also solve from the rest pose (tried after ``starts``; also used when every start is rejected).
        keep : {"lowest", "first"}
            ``"lowest"``: run every start and keep the lowest verified minimum (global). ``"first"``: stop at
            the first start that yields a verified minimum (warm, path-following: the interactive editor).
        tol, max_iter : optional
            As in :meth:`Solver.solve` (``max_iter`` per start).

        Returns
        -------
        result : SolveResult
            ``start`` names the winning start (``"start k"`` or ``"rest"``, plus any escapes);
            ``candidates`` lists (start, energy, converged) for every end point reached.
        """
        if keep not in ("lowest", "first"):
            raise ValueError(f"keep must be 'lowest' or 'first', got {keep!r}")
        self.targets_of(targets)  # bad targets raise here, not once per start
        runs = [(f"start {k}", X0) for k, X0 in enumerate(starts) if X0 is not None]
        runs += [("rest", None)] if rest else []
        results, skipped = [], []
        for label, X0 in runs:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", NotConvergedWarning)
                    r = self.solve(targets, X0=X0, tol=tol, max_iter=max_iter)
            except ValueError as exc:  # a rejected start (flipped, wrong shape): the next one
                skipped.append((label, str(exc)))
                continue
            if X0 is not None:  # "X0 > escape ..." -> "start k > escape ..."
                r.start = label + r.start[2:]
                r.candidates = [(label + lab[2:], E, ok) for lab, E, ok in r.candidates]
            results.append(r)
            if keep == "first" and r.converged:
                break
        if not results:  # every given start was rejected (flipped): the rest pose is always a valid start
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotConvergedWarning)
                results.append(self.solve(targets, tol=tol, max_iter=max_iter))
        best = min(results, key=lambda r: (not r.converged, r.energy if np.isfinite(r.energy) else np.inf))
        best.candidates = [c for r in results for c in r.candidates] + [
            (f"{label} (rejected: {why})", np.inf, False) for label, why in skipped
        ]
        if not best.converged:
            _not_converged(f"{self.energy} solve did not converge from any start: {best.reason}")
        return best


def solve(mesh, handles, targets, energy="sarap", X0=None, backend=None, **kw):
    """One-shot :class:`Solver`: ``Solver(mesh, handles, energy, backend=backend).solve(targets, X0, **kw)``.

    ``start="global"`` selects the multi-start policy of :meth:`Solver.solve_best`.

    Returns
    -------
    result : SolveResult
    """
    return Solver(mesh, handles, energy, backend=backend).solve(targets, X0=X0, **kw)


#: module functions that became :class:`Solver` methods (the old names warn and call the method)
METHODS = ("finish", "solve_best")


def __getattr__(name):
    """``finish(solver, ...)`` and ``solve_best(solver, ...)``, the old module functions: warn, call the method."""
    if name not in METHODS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warnings.warn(
        f"{__name__}.{name}(solver, ...) is deprecated and will be removed: use Solver.{name}",
        DeprecationWarning,
        stacklevel=2,
    )

    def call(solver, *args, **kwargs):
        return getattr(solver, name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    return call

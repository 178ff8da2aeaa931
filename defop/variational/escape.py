"""A saddle is not an end state: negative curvature and the escapes from points that are not minima.

When check 5 fails (:func:`defop.variational.verify.verify_point`), the solve steps off along the most negative
curvature direction (Lanczos on the reduced Hessian, run only then), in both directions, continues Newton from
each and keeps the lower verified minimum. A point held on S-ARAP's kink that the mesh pulls off it (check 4,
"kink") is left the same way, along the pull.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as sla

from .inertia import inertia_shift
from .newton import newton, step_off

#: the Krylov space of the second Lanczos attempt when ARPACK's default (20 vectors) did not converge
LARGE_NCV = 120
#: reduced Hessians of at most this many unknowns are diagonalised densely (``numpy.linalg.eigh``)
DENSE_MAX = 400
#: shift-invert Lanczos asks for every eigenvalue below −s (k = q); beyond this many, plain Lanczos (k = 1) instead:
#: ARPACK's Krylov space grows with k (at least 2k + 1 vectors of the Hessian's size)
Q_MAX = 16


def negative_curvature(solver, X, dense_max=DENSE_MAX):
    """The most negative eigenpair of the exact reduced Hessian K of the true energy at X.

    Called only when the inertia showed a negative pivot. Up to ``dense_max`` unknowns, ``numpy.linalg.eigh``.
    Above, shift-invert Lanczos (ARPACK) at σ = −s, s the diagonal shift of check 5
    (:func:`defop.variational.inertia.inertia_shift`): K + s I is factorised by the solver's own back end
    (:meth:`~defop.variational.problem.ReducedHessian.solve`), its inertia q counts the eigenvalues of K below −s
    (Sylvester), and these are exactly the q negative values of ν = 1/(λ + s), which ``eigsh(sigma=−s,
    which="SA", k=q)`` returns; the most negative λ among them is the eigenpair sought. Plain Lanczos at the bottom
    of K's spectrum (``which="SA"``), which took 588 CPU s at a saddle of the 29,739-vertex aleph, is the fallback
    when q = 0 (every negative eigenvalue within the shift), the back end gives no inertia (SuperLU) or the
    shift-invert iteration does not converge.

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    X : (n, d) numpy array
    dense_max : int, optional
        The largest number of unknowns diagonalised densely (default :data:`DENSE_MAX`).

    Returns
    -------
    lam : float
    D : (n, d) numpy array
        Unit eigenvector as a displacement field (zero at the handles). Its sign is fixed on every path: its dot
        product with a fixed seeded random vector (:func:`_sign_probe`) is positive (a largest-entry rule flips
        under round-off where a mirror-symmetric mode's entries tie); Lanczos' start vector is deterministic, and
        every eigen solve runs on one BLAS thread (two threads moved an escaped minimum by 4.8e-9 relative on the
        30k aleph: the same inputs must reach the same minimum whatever the thread count).

    Raises
    ------
    scipy.sparse.linalg.ArpackNoConvergence
        When the fallback's Lanczos converges neither with ARPACK's default Krylov space nor with
        :data:`LARGE_NCV` vectors.
    """
    from threadpoolctl import threadpool_limits

    data = solver.grad_hess(X, 0.0, project=False)[2]
    with threadpool_limits(limits=1):
        if solver.hessian.nf <= dense_max:
            lam, v = np.linalg.eigh(solver.hessian.full(data).toarray())
            found = float(lam[0]), v[:, 0]
        else:
            found = _shift_invert(solver, data) or _lowest(solver.hessian.full(data))
    lam, v = found
    v = v if v @ _sign_probe(len(v)) > 0 else -v
    return lam, solver.full(v)


def _sign_probe(n):
    """The fixed vector that sets an eigenvector's sign: seeded normal entries, the same for every n-vector."""
    return np.random.default_rng(20261202).standard_normal(n)


def _start(n):
    """ARPACK's deterministic start vector."""
    return np.ones(n) / np.sqrt(n)


def _shift_invert(solver, data):
    """(λ, (N,) v) of :func:`negative_curvature` by shift-invert Lanczos on K + s I's LDLᵀ, or None (fallback)."""
    hessian = solver.hessian
    rel = inertia_shift(solver, data)
    n = hessian.nf
    hessian.solve(data, np.zeros(n), rel)  # factorises K + s I (the back end keeps it)
    q = hessian.inertia()
    if not q or q > Q_MAX or q >= n - 1:  # no inertia (SuperLU), nothing below −s, too many, or no room for ARPACK
        return None
    M = hessian.matrix(data, rel)
    OPinv = sla.LinearOperator((n, n), matvec=lambda b: hessian.factorise(M, b), dtype=float)
    sigma = -hessian.shift(data, rel)
    try:
        lam, v = sla.eigsh(M, k=q, sigma=sigma, which="SA", OPinv=OPinv, v0=_start(n), tol=1e-6, maxiter=5000)
    except sla.ArpackNoConvergence:
        return None
    i = int(np.argmin(lam))
    return float(lam[i]), v[:, i]


def _lowest(K):
    """(λ, (N,) v): K's lowest eigenpair by plain Lanczos (``which="SA"``), a larger Krylov space when it stalls."""
    v0 = _start(K.shape[0])
    try:
        lam, v = sla.eigsh(K, k=1, which="SA", v0=v0, tol=1e-6, maxiter=5000)
    except sla.ArpackNoConvergence:  # Lanczos stalled on a cluster at the bottom: a larger Krylov space once
        lam, v = sla.eigsh(K, k=1, which="SA", v0=v0, tol=1e-6, maxiter=5000, ncv=min(K.shape[0] - 1, LARGE_NCV))
    return float(lam[0]), v[:, 0]


def escape(solver, log, X, T, tol, label, reason, ok, escapes):
    """Leave a point that is not a minimum and Newton on; keep the lower verified minimum.

    At a saddle, step off along the most negative curvature, both ways; at S-ARAP's kink (check "kink"),
    along the direction that pulls the overloaded triangles off it (:func:`defop.variational.verify.kink_pull`).
    Returns (X, label, reason, ok, check) of the best end point (``check`` its ``solver.verify``).
    """
    check = solver.verify(X, T)
    if check.failed not in ("saddle", "kink") or escapes == 0 or log.exhausted:
        log.candidates.append((label, check.energy, bool(ok and check.ok)))
        return X, label, reason, ok, check
    log.candidates.append((label, check.energy, False))
    if check.failed == "saddle":
        D = descent_direction(solver, X)
        ways = () if D is None else ((D, "escape +"), (-D, "escape -"))
        left = f"a saddle with {check.negative} negative eigenvalue(s)"
    else:
        ways = () if check.kink is None else ((check.kink, "off kink"),)
        left = "Eq. (11)'s kink, pulled off it"
    best = (X, label, reason, ok, check)
    best_key = (True, check.energy)
    for D, tag in ways:
        Xs = step_off(solver, X, D)
        if Xs is None or log.exhausted:
            continue
        Xs, ok_s, why = newton(solver, log, Xs, tol)
        why = f"{why} (escaped {left})"
        lab = f"{label} > {tag}"
        out = escape(solver, log, Xs, T, tol, lab, why, ok_s, escapes - 1)
        key = (not (out[3] and out[4].ok), out[4].energy)
        if key < best_key:
            best, best_key = out, key
    return best


def descent_direction(solver, X):
    """The most negative curvature direction at X, or None when Lanczos does not converge: the point then stays
    what it is, a saddle and not a verified minimum (no crash of the solve or of the batch it is in)."""
    try:
        return negative_curvature(solver, X)[1]
    except sla.ArpackNoConvergence:
        return None

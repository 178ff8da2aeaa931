"""A saddle is not an end state: negative curvature and the escapes from points that are not minima.

When check 5 fails (:func:`defop.variational.verify.verify_point`), the solve steps off along the most negative
curvature direction (Lanczos on the reduced Hessian, run only then), in both directions, continues Newton from
each and keeps the lower verified minimum. A point held on S-ARAP's kink that the mesh pulls off it (check 4,
"kink") is left the same way, along the pull.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as sla

from .newton import newton, step_off

#: the Krylov space of the second Lanczos attempt when ARPACK's default (20 vectors) did not converge
LARGE_NCV = 120


def negative_curvature(solver, X):
    """The most negative eigenpair of the exact reduced Hessian of the true energy at X.

    Lanczos (ARPACK) on the free-free block; called only when the inertia showed a negative pivot.

    Returns
    -------
    lam : float
    D : (n, d) numpy array
        Unit eigenvector as a displacement field (zero at the handles).

    Raises
    ------
    scipy.sparse.linalg.ArpackNoConvergence
        When Lanczos converges neither with ARPACK's default Krylov space nor with :data:`LARGE_NCV` vectors.
    """
    data = solver.grad_hess(X, 0.0, project=False)[2]
    K = solver.hessian.full(data)
    if K.shape[0] <= 400:
        lam, v = np.linalg.eigh(K.toarray())
        lam, v = lam[:1], v[:, :1]
    else:
        v0 = np.ones(K.shape[0]) / np.sqrt(K.shape[0])  # deterministic start vector
        try:
            lam, v = sla.eigsh(K, k=1, which="SA", v0=v0, tol=1e-6, maxiter=5000)
        except sla.ArpackNoConvergence:  # Lanczos stalled on a cluster at the bottom: a larger Krylov space once
            lam, v = sla.eigsh(K, k=1, which="SA", v0=v0, tol=1e-6, maxiter=5000, ncv=min(K.shape[0] - 1, LARGE_NCV))
    return float(lam[0]), solver.full(v[:, 0])


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

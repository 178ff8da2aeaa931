"""The one diagonal-shift policy of the exact reduced Hessian: what a factorisation adds to its diagonal before its
inertia is read or its Newton direction is used.

One function, :func:`inertia_shift`, serves every exact-Hessian factorisation outside Newton's own steps:

* check 5 of the verification (:func:`defop.variational.verify.verify_point`): the negative pivots of the shifted
  LDLᵀ are the negative eigenvalues (Sylvester's law of inertia), and the shift decides what counts as round-off;
* the kink certificate (:func:`defop.variational.kink.newton_decrement` in
  :func:`defop.variational.kink.smoothing_certificate`): it also counts negative pivots;
* the held set's pull (:func:`defop.variational.kink.kink_gap` and :func:`defop.variational.newton.kink_active_set`):
  the shift regularises the Newton direction whose held-mode amplitudes give the pull on the kink.

A shift of the *mean* |diagonal| (``INERTIA_SHIFT`` of it) would be dominated by the stiff held modes of S-ARAP
triangles on the kink (benchmarks/bench_inertia_shift.py compares both policies sample by sample).
"""

from __future__ import annotations

import numpy as np

#: relative diagonal shift under which a negative Hessian eigenvalue counts as round-off (check 5)
INERTIA_SHIFT = 1e-8
#: the shift is at least this many units of round-off of the largest diagonal entry (:func:`inertia_shift`)
ROUNDOFF = 100.0


def inertia_shift(solver, data):
    """The diagonal shift of an exact-Hessian factorisation, as the share of the mean |diagonal| that
    ``ReducedHessian.matrix`` takes (its ``rel_shift``).

    ``INERTIA_SHIFT`` of the median |diagonal|, at least ``ROUNDOFF`` · ε · max|diagonal| and at most
    ``INERTIA_SHIFT`` of the mean. The mean alone is dominated by the stiff held modes of S-ARAP triangles on the
    kink: at the bar's S-shaped saddle (handle pushed in by 0.3, 3 held triangles) the mean |diagonal| was 2.6e7
    against a median of 8.8, so a shift of 0.26 hid the held Hessian's eigenvalue −1.9e-3 and check 5 accepted
    the saddle as a minimum (tests/test_saddle.py).

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    data : (nnz,) numpy array
        Values of the exact reduced Hessian (its ``hessian`` pattern).

    Returns
    -------
    rel_shift : float
        At most ``INERTIA_SHIFT``.
    """
    d = np.abs(data[solver.hessian.diag])
    mean = max(float(d.mean()), 1e-300)
    shift = max(INERTIA_SHIFT * float(np.median(d)), ROUNDOFF * np.finfo(float).eps * float(d.max()))
    return min(shift, INERTIA_SHIFT * mean) / mean

"""The constrained least-squares fit of a DefOp: problem (8) and Appendix A.

Given training configurations Q_k (the rest pose Q_0 = P is always added) and their variational
deformations X_k = D^E(·, Q_k), find the coefficients C (|Φ| × |Ψ|, one matrix per coordinate) of
D(·, Q) = U C Ψ(Q) (Eq. 3) that

    minimise   Σ_k ‖X_k − U C Ψ(Q_k)‖²_M                     (8a, the L² norm of Appendix A)
    subject to U C Ψ(P) = V                                  (8b, the rest pose is reproduced)
               D(p_h, Q_k) = q_{h,k} for every handle h, k   (8c, the handles are interpolated)
               C Tᵀ = 0                                       (TPS side conditions)

Solved through its structure, never as one dense system over |Φ|·|Ψ| unknowns:

* (8c) together with (8b) and the side conditions says that the rows W C of the handle vertices
  (W = U[handles]) equal the coefficients L of the handles' own linear motion (the TPS / polynomial
  interpolant of linear data is that linear function), so C = W⁺L + (I − W⁺W) Ĉ (for hat functions:
  the handle rows of C are L);
* Ĉ solves the row-decoupled problem min ‖B − Ĉ Sᵀ‖² s.t. Ĉ Aᵀ = [a, 0], with S (m × |Ψ|) the
  samples' Ψ values, A = [Ψ(P)ᵀ; T] and B, a the L²-projections of the data and the rest pose onto Φ.
  Every row shares the same small |Ψ|-sized constrained least-squares problem, solved once by the
  null-space method: Ĉ = B Gᵀ + a βᵀ with G (|Ψ| × m) and β (|Ψ|,) from a QR of S N (N a basis of
  null A). With Φ M-orthonormal (reduced) or hat functions with a lumped M, the M-weighted objective is
  exactly this row-wise one.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla

from .. import options as opt
from . import handle_bases as hb
from . import spatial as spatial_mod


def solve_structure(S, A, rcond=1e-13):
    """The shared small problem: G, β with Ĉ = B Gᵀ + a βᵀ for every row.

    Null-space method: with A = [Ψ(P)ᵀ; T], Qa = [Q1 Q2] from a Householder QR of Aᵀ (kept in
    factored form and applied with LAPACK's ``ormqr``: the |Ψ| × |Ψ| matrix is never formed), every
    row is c = α a + Q2 y with A α = e_0 and y the least-squares solution of (S Q2) y = b − S α a.
    The rest pose (row 0 of S) is already fixed by the constraint, so rows 1.. carry the data; when
    S[1:] Q2 is square (the TPS case: one function per sample) it is solved by LU, otherwise by a
    rank-revealing QR.

    Parameters
    ----------
    S : (m,q) numpy array
        Ψ at the samples (the rest pose first).
    A : (r,q) numpy array
        Constraint rows: Ψ(P) first, then side conditions.
    rcond : float
        Relative threshold for the numerical rank.

    Returns
    -------
    G : (q,m) numpy array
    beta : (q,) numpy array
    rank : int
        Numerical rank of S[1:] Q2 (q − r when the samples determine the fit).
    """
    m, q = S.shape
    r = A.shape[0]
    qr_raw, tau = sla.qr(A.T, mode="raw")[0]
    Rr = np.triu(qr_raw[:r, :r])

    def apply_Q(C, side, trans):
        lwork = max(1, 64 * max(C.shape))
        out, _, info = sla.lapack.dormqr(side, trans, qr_raw, tau, np.asfortranarray(C), lwork)
        if info != 0:  # pragma: no cover
            raise RuntimeError(f"LAPACK dormqr failed with info={info}")
        return out

    e0 = np.zeros(q)
    e0[:r] = sla.solve_triangular(Rr.T, np.eye(r)[:, 0], lower=True)
    alpha = apply_Q(e0[:, None], "L", "N")[:, 0]  # A α = e_0, minimum norm
    SQ = apply_Q(S, "R", "N")  # S Qa
    SN = SQ[1:, r:]  # (m-1, q-r): data rows in null-space coordinates
    qq = q - r
    Y = np.zeros((qq, m))  # y = Y (b - S α a): maps the m data values to null-space coordinates
    rank = 0
    if SN.shape[0] == qq:
        lu, piv = sla.lu_factor(SN, check_finite=False)
        rc = sla.lapack.dgecon(lu, np.linalg.norm(SN, 1), norm="1")[0]
        if rc > rcond:
            Y[:, 1:] = sla.lu_solve((lu, piv), np.eye(qq), check_finite=False)
            rank = qq
    if rank == 0:
        Qs, Rs, pv = sla.qr(SN, mode="economic", pivoting=True)
        diag = np.abs(np.diag(Rs))
        rank = int(np.sum(diag > rcond * diag.max())) if len(diag) else 0
        Y[pv[:rank], 1:] = sla.solve_triangular(Rs[:rank, :rank], Qs[:, :rank].T)
    Z = np.zeros((q, m))
    Z[r:] = Y
    G = apply_Q(Z, "L", "N")  # (q, m) = Q2 Y
    beta = alpha - G @ (S @ alpha)
    return G, beta, rank


def solve_structure_tps(S, d):
    """:func:`solve_structure` for TPS interpolation (centres = the samples), through a symmetric system.

    With as many centres as samples the fit interpolates: K w + P p = y, Pᵀ w = 0, where K is the
    (symmetric) kernel matrix φ(‖z_k − z_j‖) and P = [1, z_k]. With a Householder QR P = [Qp Qn][R; 0],
    w = Qn v and H v = Qnᵀ y for H = Qnᵀ K Qn, which is positive definite because the kernel (r² log r in
    2D, r³ in 3D, :mod:`defop.operator.handle_bases`) is conditionally positive definite of order 2 (in any
    dimension of the handle space). So: a Cholesky factorisation and
    inverse of H (LAPACK potrf/potri, about a third of the work of the general LU-and-solve); the 1 + d
    Householder reflectors enter in compact WY form, as rank-(1 + d) updates; and R p = Qpᵀ (y − K w).

    Parameters
    ----------
    S : (m,q) numpy array
        Ψ at the samples, q = 1 + d + m: columns 1, z (d), then φ at the m centres (the samples, same order).
    d : int
        Dimension of z (d × moving handles, for handles in R^d).

    Returns
    -------
    G, beta, rank : as :func:`solve_structure`, or None when H is not numerically positive definite or
        [1, z] is rank deficient (the caller falls back to the general method; :func:`structure` sends samples in
        an affine subspace there first, by :func:`unspanned`).
    """
    m, q = S.shape
    r = 1 + d
    K = S[:, r:]
    qr_raw, tau = sla.qr(S[:, :r], mode="raw")[0]
    Rp = np.triu(qr_raw[:r, :r])
    diag = np.abs(np.diag(Rp))
    if diag.min() <= 1e-10 * diag.max():  # samples in an affine subspace: the general method (side_conditions)
        return None
    # compact WY form of the r Householder reflectors: [Qp Qn] = I − U Vᵀ with U = V T (LAPACK's dlarft)
    V = np.tril(qr_raw[:, :r], -1)
    V[np.arange(r), np.arange(r)] = 1.0
    T = np.zeros((r, r))
    for i in range(r):
        T[i, i] = tau[i]
        T[:i, i] = -tau[i] * (T[:i, :i] @ (V[:, :i].T @ V[:, i]))
    U = V @ T
    Vr = V[r:]  # rows r.. of V: Qn = E − U Vrᵀ with E = [0; I]
    KU = K @ U
    UKU = U.T @ KU
    # H = Qnᵀ K Qn, by rank-r updates of K's trailing block (no m x m products)
    H = K[r:, r:] - KU[r:] @ Vr.T - Vr @ KU[r:].T + Vr @ UKU @ Vr.T
    c, info = sla.lapack.dpotrf(H, lower=0, overwrite_a=1)
    if info != 0:
        return None
    Hi, info = sla.lapack.dpotri(c, lower=0, overwrite_c=1)
    if info != 0:  # pragma: no cover
        return None
    Hi = np.triu(Hi) + np.triu(Hi, 1).T
    # Wm = Qn H⁻¹ Qnᵀ (y ↦ w): expand (E − U Vrᵀ) H⁻¹ (E − U Vrᵀ)ᵀ
    B = Vr.T @ Hi  # (r, m − r)
    UB = U @ B
    Wm = U @ (B @ Vr) @ U.T
    Wm[r:, r:] += Hi
    Wm[:, r:] -= UB
    Wm[r:, :] -= UB.T
    # p = R⁻¹ Qpᵀ (y − K w) with Qp = E0 − U V[:r]ᵀ
    Qp = -U @ V[:r].T
    Qp[np.arange(r), np.arange(r)] += 1.0
    Pm = sla.solve_triangular(Rp, Qp.T - (Qp.T @ K) @ Wm)
    M = np.vstack([Pm, Wm])  # (q, m): y ↦ c = [p; w]
    beta = M[:, 0].copy()  # the rest pose's value
    M[:, 0] = 0.0
    return M, beta, m - 1


def check_distinct(samples):
    """Raise ValueError naming the first two equal samples Q_k (the tps basis centres a function on each).

    Parameters
    ----------
    samples : (m,n,d) numpy array
    """
    rows = np.asarray(samples).reshape(len(samples), -1)
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    dup = np.flatnonzero(first[inverse.ravel()] != np.arange(len(rows)))
    if len(dup):
        k = int(dup[0])
        raise ValueError(
            f"samples {int(first[inverse.ravel()[k]])} and {k} are the same handle configuration: the tps basis "
            "needs distinct samples (its centres)"
        )


def fit(mesh, handles, moving, samples, X, basis="tps", spatial="hat", k=100, scale=None, meta=None):
    """Fit a :class:`defop.operator.DefOp` to sampled deformations: problem (8).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        Triangles (V (n_vertices, 2)) or tetrahedra (V (n_vertices, 3)); d is read from V. Its lumped
        ``mass_matrix`` (areas, or volumes) is the M of (8a).
    handles : (h,) int numpy array
        Vertex indices of all handles.
    moving : (h,) bool numpy array
        Which handles move (the variables of Ψ).
    samples : (m,n,d) numpy array
        Q_k, positions of the moving handles (n = moving.sum()).
    X : (m,n_vertices,d) numpy array
        D^E(·, Q_k), the variational deformations at the samples.
    basis : str or defop.operator.handle_bases.HandleBasis
        ``"linear"``, ``"quadratic"``, ``"cubic"`` or ``"tps"`` (centred at the samples and the rest pose).
    spatial : str or defop.operator.spatial.SpatialBasis
        ``"hat"`` or ``"reduced"`` (with ``k`` functions).
    k : int
        Size of the reduced spatial basis.
    scale : float, optional
        Length normalising handle displacements in Ψ (default: the RMS sample displacement).
    meta : dict, optional
        Extra metadata stored with the operator (shape name, energy, ...).

    Returns
    -------
    defop : defop.operator.DefOp
        With ``defop.fit_time`` (seconds for the small structured solve) and ``defop.fold_time``.

    Raises
    ------
    ValueError
        Shapes that do not match, NaN, too few samples for the basis (the message says the minimum),
        duplicate samples for TPS.
    """
    from .defop import DefOp

    handles = np.asarray(handles, dtype=np.int64)
    moving = np.asarray(moving, dtype=bool)
    Qs, Xs = _with_rest_pose(mesh, handles, moving, samples, X, basis)
    psi = _handle_basis(basis, Qs, scale)
    if isinstance(spatial, str):
        spatial = spatial_mod.make_spatial(mesh, spatial, k)

    t0 = time.perf_counter()
    G, beta = structure(psi, Qs)
    fit_time = time.perf_counter() - t0

    t1 = time.perf_counter()
    Wf = fold(mesh, handles, moving, psi, spatial, G, beta, Xs)
    fold_time = time.perf_counter() - t1
    meta = dict(meta or {})
    meta.update(basis=psi.kind, spatial=spatial.kind, spatial_size=spatial.size, n_samples=len(Qs) - 1)
    op = DefOp(mesh, handles, moving, psi, Wf.reshape(psi.size, -1), meta=meta, train_samples=Qs)
    op.fit_time, op.fold_time = fit_time, fold_time
    return op


def structure(psi, Qs):
    """G (|Ψ|, m), β (|Ψ|,) of problem (8) for the samples Qs (m, n, d), the rest pose first.

    The fit of any per-sample data Y (m, ...) with the rest pose's value Y[0] is G Y + β Y[0] (Appendix A, the
    module docstring): :func:`fold` uses it for the deformations, :func:`fit_values` for a scalar per sample.

    Raises
    ------
    ValueError
        Samples that do not determine the basis (the message says how many it needs).
    """
    S = psi.evaluate_z(psi.z(Qs))  # (m, q)
    T, pinned = side_conditions(psi)
    A = np.vstack([S[:1], T])
    fast = None
    if psi.kind == "tps" and S.shape[1] == 1 + psi.dim + len(S) and not pinned:  # the symmetric TPS system
        fast = solve_structure_tps(S, psi.dim)
    G, beta, rank = fast if fast is not None else solve_structure(S, A)
    if rank < A.shape[1] - A.shape[0]:
        raise ValueError(
            f"the samples do not determine the {psi.kind} basis (rank {rank} < {A.shape[1] - A.shape[0]}): "
            f"too few or degenerate samples; it needs at least {psi.min_samples() - 1} distinct ones"
        )
    return G, beta


#: :func:`unspanned`: a direction along which the centres spread less than this share of their largest spread
#: counts as not spanned (between 1e-10 and 1e-6 the interpolant's linear part along it grew to 1e3–1e5 off the plane)
SPAN_RCOND = 1e-6


def farthest_points(X, k, first=0):
    """Indices (k,) of ``k`` rows of X (N, ...) picked greedily, each the farthest (Euclidean, rows flattened) from
    those picked before, row ``first`` first: a spread subset, e.g. the centres of a TPS with fewer centres than
    samples (:func:`structure` then fits the samples by least squares)."""
    X = np.asarray(X, float).reshape(len(X), -1)
    k = min(int(k), len(X))
    pick = np.empty(k, np.int64)
    pick[0] = first
    d2 = np.sum((X - X[first]) ** 2, axis=1)
    for i in range(1, k):
        pick[i] = j = int(np.argmax(d2))
        d2 = np.minimum(d2, np.sum((X - X[j]) ** 2, axis=1))
    return pick


def centre_count(centres, m, n_points):
    """How many of ``n_points`` points (m samples and their rest poses) a least-squares TPS keeps as centres
    (:func:`defop.operator.movable.fit_movable`, picked by :func:`farthest_points`): ``"auto"`` m + 1, as many as a
    fixed-P TPS of m samples has, whatever the shape; None all (interpolation); an int that many (at most all)."""
    if centres is None:
        return n_points
    if isinstance(centres, str) and centres == "auto":
        return min(m + 1, n_points)
    return min(opt.integer("centres", centres, 1), n_points)


def unspanned(z, rcond=SPAN_RCOND):
    """Directions (dim, k), orthonormal, in which the points z (m, dim) never move: the complement of their affine hull.

    Returns
    -------
    N : (dim, k) numpy array
        k = dim − the affine hull's dimension (0 columns when the points span every direction).
    B : (dim, dim − k) numpy array
        An orthonormal basis of the hull's directions.
    """
    D = np.asarray(z, dtype=float)[1:] - np.asarray(z, dtype=float)[:1]
    dim = D.shape[1]
    if len(D) == 0:
        return np.eye(dim), np.zeros((dim, 0))
    _, s, Vt = np.linalg.svd(D, full_matrices=False)  # thin: (min(m − 1, dim), dim), no (m − 1)² factor
    r = int(np.sum(s > rcond * max(float(s.max()), 1e-300)))
    B = Vt[:r].T
    N = np.linalg.qr(B, mode="complete")[0][:, r:] if r else np.eye(dim)
    return N, B


def side_conditions(psi):
    """The side conditions of Ψ, with the TPS linear part pinned where its centres never move.

    When every centre (every Q_k: the fit centres a TPS function on each sample) lies in an affine subspace of the
    handle space (in 3D one handle dragged in a plane, or a patch of handles moved together), Σ_k w_k (z_k · n) = 0
    repeats Σ_k w_k = 0 for every direction n out of it, and the linear coefficient along n is determined by no
    sample. Those rows are replaced by "the coefficient along n is 0", the minimum-norm choice: on the subspace the
    fit is the TPS interpolant of the samples in its own coordinates; off it only the radial terms see the distance
    to it, and the handles, whose rows :func:`fold` sets to their linear motion, stay exact (Prop. 2). With the hat
    basis the vertices next to a handle that leaves the subspace then barely follow it, and no warning says so
    (the extrapolation warning measures the distance from rest only). Other bases: ``psi.side_conditions()``.

    Returns
    -------
    T : (s, |Ψ|) numpy array
    pinned : int
        How many directions were pinned (0: T is ``psi.side_conditions()``).
    """
    T = psi.side_conditions()
    if psi.kind != "tps":
        return T, 0
    N, B = unspanned(psi.z(psi.centers))
    if N.shape[1] == 0:
        return T, 0
    pins = np.zeros((N.shape[1], psi.size))
    pins[:, 1 : 1 + psi.dim] = N.T
    return np.vstack([T[:1], B.T @ T[1 : 1 + psi.dim], pins]), N.shape[1]


def fit_values(op, values):
    """Coefficients w (|Ψ|,) of a scalar closed form f(Q) = Ψ(Q) · w fitted like problem (8), with ``op``'s Ψ.

    The same least-squares structure as the operator's (for TPS: interpolation at the same centres), so a
    per-branch energy E_b(Q) or stability margin costs one dot product more than D_b(·, Q).

    Parameters
    ----------
    op : defop.operator.DefOp
        A fitted operator with its ``train_samples`` (m, n, d), the rest pose first (as :func:`fit` stores them).
    values : (m,) numpy array
        The value at each of ``op.train_samples`` (the rest pose's first; f(P) = values[0] exactly).

    Returns
    -------
    w : (|Ψ|,) numpy array
    """
    Qs = op.train_samples
    if Qs is None:
        raise ValueError("op must hold its training samples (train_samples) to fit values with its basis")
    values = np.asarray(values, dtype=float)
    if values.shape != (len(Qs),) or not np.isfinite(values).all():
        raise ValueError(f"values must be {len(Qs)} finite numbers, one per training sample, got shape {values.shape}")
    G, beta = structure(op.handle_basis, Qs)
    return G @ values + beta * values[0]


def _with_rest_pose(mesh, handles, moving, samples, X, basis):
    """(Qs (m,n,d), Xs (m,n_vertices,d)): the checked samples and deformations, the rest pose first (once)."""
    P = mesh.V[handles[moving]]
    n, d = P.shape
    samples = np.asarray(samples, dtype=float)
    X = np.asarray(X, dtype=float)
    if samples.ndim != 3 or samples.shape[1:] != (n, d):
        raise ValueError(f"samples must have shape (m, {n}, {d}) for {n} moving handles, got {samples.shape}")
    if X.shape != (len(samples), mesh.n_vertices, d):
        raise ValueError(
            f"X must have shape ({len(samples)}, {mesh.n_vertices}, {d}), one deformation per sample, got {X.shape}"
        )
    if not (np.isfinite(samples).all() and np.isfinite(X).all()):
        raise ValueError("samples or X contain NaN or infinite values")
    if isinstance(basis, str) and basis == "tps":
        check_distinct(samples)
    # the rest pose is always a training sample: D^E(·, P) = identity
    at_rest = np.abs(samples - P).reshape(len(samples), -1).max(axis=1) <= 1e-14
    return np.concatenate([P[None], samples[~at_rest]]), np.concatenate([mesh.V[None], X[~at_rest]])


def _handle_basis(basis, Qs, scale):
    """Ψ by name (or as given) for the samples Qs (rest pose first), with enough samples for it."""
    P, m = Qs[0], len(Qs)
    n, d = P.shape
    if scale is None:
        disp = np.sqrt(np.mean(np.sum((Qs[1:] - P) ** 2, axis=-1))) if m > 1 else 1.0
        scale = float(disp) if disp > 0 else 1.0
    if isinstance(basis, str):
        if basis not in hb.KINDS:
            raise ValueError(f"unknown handle basis {basis!r}; known: {', '.join(hb.KINDS)}")
        if basis == "tps":
            need = d * n + 2
            if m < need:
                raise ValueError(
                    f"the tps basis needs at least {need} samples with the rest pose ({need - 1} "
                    f"besides it) for {n} moving handles, got {m - 1}"
                )
        psi = hb.make_basis(basis, P, centers=Qs if basis == "tps" else None, scale=scale)
    else:
        psi = basis
    if m < psi.min_samples():
        need = psi.min_samples()
        raise ValueError(
            f"the {psi.kind} basis (|Ψ| = {psi.size}) needs at least {need} samples with the rest "
            f"pose ({need - 1} besides it) for {n} moving handles, got {m - 1}"
        )
    return psi


def fold(mesh, handles, moving, psi, spatial, G, beta, Xs):
    """The folded coefficients W (|Ψ|, n_vertices, d): Φ folded in, the handle rows fixed by Prop. 2 / (8c).

    Parameters
    ----------
    G, beta : (q,m) and (q,) numpy arrays
        From :func:`solve_structure` (or :func:`solve_structure_tps`).
    Xs : (m,n_vertices,d) numpy array
        The deformations, the rest pose first.

    Returns
    -------
    W : (q,n_vertices,d) numpy array
    """
    q, d = psi.size, psi.d
    # coefficients of the handles' linear motion, per handle vertex and coordinate: (h, q, d)
    L = np.zeros((len(handles), q, d))
    mv = np.flatnonzero(moving)
    for c in range(d):
        L[~moving, 0, c] = mesh.V[handles[~moving], c]
        for j, h in enumerate(mv):
            L[h, :, c] = psi.linear_coefficients(j, c)
    if spatial.kind == "hat":
        # W_c = X_c Gᵀ + V_c βᵀ, handle rows replaced by L (exact interpolation, Prop. 2)
        Wf = (G @ Xs.reshape(len(Xs), -1) + np.outer(beta, mesh.V.ravel())).reshape(q, -1, d)  # BLAS, not einsum
        Wf[:, handles, :] = np.transpose(L, (1, 0, 2))
        return Wf
    U = spatial.U
    B = spatial.coefficients(Xs)  # (m, p, d)
    a = spatial.coefficients(mesh.V)  # (p, d)
    Chat = np.stack([B[:, :, c].T @ G.T + np.outer(a[:, c], beta) for c in range(d)], axis=-1)  # (p, q, d)
    Wh = U[handles]  # (h, p)
    Wp = np.linalg.pinv(Wh)  # (p, h)
    C = Chat + np.einsum("ph,hqc->pqc", Wp, L - np.einsum("hp,pqc->hqc", Wh, Chat))
    return np.stack([(U @ C[:, :, c]).T for c in range(d)], axis=-1)  # (q, v, d), by BLAS


def fit_shape(shape, samples, X, basis="tps", spatial="hat", k=100, **kw):
    """:func:`fit` for a :class:`defop.scene.shapes.Shape` (its mesh, handles and moving flags).

    Returns
    -------
    defop : defop.operator.DefOp
    """
    meta = {"shape": shape.name, **kw.pop("meta", {})}
    return fit(shape.mesh, shape.handles, shape.moving, samples, X, basis, spatial, k, meta=meta, **kw)

"""Independent 3D references for the volumetric energies and, later, the 3D solver (issue 27 §2).

Nothing here uses the analytic eigensystem of :mod:`defop.variational.volumetric`: the total energy
E(X) = Σ_t vol_t ψ(J_t) is assembled from tetrahedra directly (J_t = D(X) D(V)⁻¹ with D the edge matrix
[x₁ − x₀, x₂ − x₀, x₃ − x₀]); only ψ(J) per tetrahedron (``density``, a function of J's singular values) is
shared. :func:`fd_newton` minimises it by Newton with finite-difference gradients and Hessians;
:func:`libigl_arap` runs libigl's element ARAP, whose energy is the same as ``"arap"`` up to a constant
(:func:`libigl_element_arap_energy`, checked in tests/test_energies_3d.py).
"""

from __future__ import annotations

import numpy as np

from defop.variational import volumetric as vo

#: the six tetrahedra of a unit cube around its diagonal 0–7 (Kuhn/Freudenthal), corners numbered by bits (x,y,z)
_KUHN = ((0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7))


def grid_tets(k=2, size=1.0):
    """A k×k×k grid of cubes, six tetrahedra each, all positively oriented.

    Returns
    -------
    V : (n,3) numpy array
        n = (k+1)³ vertices in [0, size]³.
    T : (6k³,4) int numpy array
    """
    return box_tets((k, k, k), (size, size, size))


def box_tets(cells, size):
    """A box [0, size₀]×[0, size₁]×[0, size₂] of cells₀×cells₁×cells₂ boxes, six tetrahedra each (Kuhn).

    Returns
    -------
    V : (n,3) numpy array
        n = Π (cellsᵢ + 1), numbered with the last axis fastest.
    T : (6 Π cellsᵢ,4) int numpy array
        Positively oriented.
    """
    cells = np.asarray(cells)
    axes = [np.arange(c + 1) for c in cells]
    ix = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    V = ix * (np.asarray(size, dtype=float) / cells)
    index = {tuple(p): i for i, p in enumerate(ix)}
    T = []
    for c in ix[(ix < cells).all(axis=1)]:
        corner = [index[tuple(c + [(b >> 0) & 1, (b >> 1) & 1, (b >> 2) & 1])] for b in range(8)]
        T += [[corner[i] for i in tet] for tet in _KUHN]
    T = np.array(T)
    flip = volumes(V, T) < 0
    T[flip] = T[flip][:, [0, 2, 1, 3]]
    return V, T


def twisted_cube(seed, k=2):
    """A k×k×k grid whose 8 corners are handles in a random order: bottom fixed, top twisted about z and moved.

    Returns
    -------
    V : (n,3) numpy array
    T : (m,4) int numpy array
    handles : (8,) int numpy array
        Corner vertices, permuted by ``seed``.
    targets : (8,3) numpy array
    """
    rng = np.random.default_rng(seed)
    V, T = grid_tets(k)
    handles = rng.permutation(np.flatnonzero(((V == 0) | (V == 1)).all(axis=1)))
    ang = rng.uniform(0.2, 0.6)
    Rz = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    targets = V[handles].copy()
    top = targets[:, 2] == 1
    targets[top] = (targets[top] - 0.5) @ Rz.T + 0.5 + rng.uniform(-0.1, 0.2, 3)
    return V, T, handles, targets


def _edges(X, T):
    X = np.asarray(X, dtype=float)
    return np.swapaxes(X[..., T[:, 1:], :] - X[..., T[:, :1], :], -1, -2)  # (..., m, 3, 3): columns are edges


def volumes(V, T):
    """Signed volumes (m,) of the tetrahedra."""
    return np.linalg.det(_edges(V, T)) / 6


def jacobians(V, T, X):
    """J_t (…, m, 3, 3) with X_t = J_t V_t on each tetrahedron's edges; X may be a batch (k, n, 3)."""
    return _edges(X, T) @ np.linalg.inv(_edges(V, T))


def total_energy(V, T, X, energy, mu=0.0):
    """E(X) = Σ_t vol_t ψ(J_t), one value or one per configuration of a batch X (k, n, 3)."""
    X = np.asarray(X, dtype=float)
    J = jacobians(V, T, X)
    psi = vo.density(J.reshape(-1, 3, 3), energy, mu).reshape(J.shape[:-2])
    return psi @ volumes(V, T)


def _fd_grad_hess(V, T, X, energy, mu=0.0, h=1e-4, hg=1e-6):
    """E(X), its gradient (3n,) and Hessian (3n,3n) by central differences, assembled from the tetrahedra.

    Per tetrahedron, vol_t ψ(J_t) as a function of its 12 corner coordinates is differenced (gradient with step
    ``hg``, Hessian with ``h``) in one batched evaluation, then summed into the global arrays.
    """
    X = np.asarray(X, dtype=float)
    Dinv = np.linalg.inv(_edges(V, T))
    vol = volumes(V, T)
    I = np.eye(12)
    pp, pm = (I[:, None, :] + I[None, :, :]).reshape(-1, 12), (I[:, None, :] - I[None, :, :]).reshape(-1, 12)
    steps = np.concatenate([hg * I, -hg * I, h * pp, -h * pp, h * pm, -h * pm])  # (24 + 4·144, 12)
    xt = X[T].reshape(1, -1, 12) + steps[:, None, :]  # (s, m, 12)
    x = xt.reshape(len(steps), -1, 4, 3)
    J = np.swapaxes(x[:, :, 1:] - x[:, :, :1], -1, -2) @ Dinv
    E = vo.density(J.reshape(-1, 3, 3), energy, mu).reshape(len(steps), -1) * vol  # (s, m)
    g = (E[:12] - E[12:24]).T / (2 * hg)  # (m, 12)
    a, b, c, d = (E[24 + q * 144 : 24 + (q + 1) * 144].T.reshape(-1, 12, 12) for q in range(4))
    H = (a + b - c - d) / (4 * h * h)  # E(x ± h(eᵢ + eⱼ)) − E(x ± h(eᵢ − eⱼ)) = 4h² Hᵢⱼ + O(h⁴)
    dofs = (3 * T[:, :, None] + np.arange(3)).reshape(-1, 12)
    n3 = X.size
    G = np.bincount(dofs.ravel(), g.ravel(), minlength=n3)
    rows, cols = np.broadcast_arrays(dofs[:, :, None], dofs[:, None, :])
    Hg = np.bincount((rows * n3 + cols).ravel(), ((H + np.swapaxes(H, 1, 2)) / 2).ravel(), minlength=n3 * n3)
    return G, Hg.reshape(n3, n3)


def fd_newton(V, T, handles, targets, energy="arap", X0=None, tol=1e-7, max_iter=60, mu=0.0):
    """Minimise E(X) = Σ_t vol_t ψ(J_t) with the handles fixed, by Newton on finite differences (a reference).

    The Hessian is projected to its positive part by an eigen-decomposition (dense: meant for ≲ 100 free
    coordinates), the step backtracks until E decreases (+inf counts as no decrease, so barriers stay valid).

    Parameters
    ----------
    V : (n,3) numpy array
    T : (m,4) int numpy array
    handles : (h,) int sequence
    targets : (h,3) numpy array
    energy : str
    X0 : (n,3) numpy array, optional
        Start (rest pose with the handles moved, by default); must have finite energy.

    Returns
    -------
    X : (n,3) numpy array
    info : dict
        ``energy``, ``grad_norm`` (max |∂E/∂x| over free coordinates, by finite differences), ``iterations``.
    """
    handles = np.asarray(handles)
    X = np.array(V if X0 is None else X0, dtype=float)
    X[handles] = targets
    fixed = np.zeros(X.shape, bool)
    fixed[handles] = True
    free = np.flatnonzero(~fixed.ravel())
    E = total_energy(V, T, X, energy, mu)
    if not np.isfinite(E):
        raise ValueError(f"X0 must have finite {energy} energy (no inverted tetrahedra), got E = {E}")
    iterations = 0
    while True:
        g, H = _fd_grad_hess(V, T, X, energy, mu)
        g, H = g[free], H[np.ix_(free, free)]
        if np.abs(g).max() < tol or iterations == max_iter:
            break
        lam, Q = np.linalg.eigh(H)
        p = -Q @ ((Q.T @ g) / np.maximum(lam, 1e-8 * max(lam.max(), 1.0)))
        t = 1.0
        while t > 1e-12:
            Xn = X.copy()
            Xn.ravel()[free] += t * p
            En = total_energy(V, T, Xn, energy, mu)
            if En < E:
                break
            t /= 2
        else:
            break
        X, E, iterations = Xn, En, iterations + 1
    return X, {"energy": float(E), "grad_norm": float(np.abs(g).max()), "iterations": iterations}


def libigl_element_arap_energy(V, T, X):
    """libigl's element ARAP energy, Σ_t Σ_edges c_te ‖(x_i − x_j) − R_t (v_i − v_j)‖², R_t the best rotation.

    The weights c_te are ``igl.cotmatrix_entries`` (edges [1,2], [2,0], [0,1], [3,0], [3,1], [3,2]), as in
    libigl's ``arap_linear_block_elements``; R_t is the rotation fitted to J_t (signed SVD: U Vᵀ).
    """
    import igl

    C = igl.cotmatrix_entries(np.asarray(V, float), np.asarray(T, np.int64))
    U, _, W = vo.signed_svd(jacobians(V, T, X))
    R = U @ np.swapaxes(W, 1, 2)
    pairs = ((1, 2), (2, 0), (0, 1), (3, 0), (3, 1), (3, 2))
    E = np.zeros(len(T))
    for e, (i, j) in enumerate(pairs):
        d = X[T[:, i]] - X[T[:, j]] - np.einsum("mab,mb->ma", R, V[T[:, i]] - V[T[:, j]])
        E += C[:, e] * (d * d).sum(axis=1)
    return E


def libigl_arap(V, T, handles, targets, iterations=2000, X0=None):
    """libigl's local–global ARAP on tetrahedra (``ARAP_ENERGY_TYPE_ELEMENTS``, dim 3), many iterations.

    V, T, handles, targets as in :func:`fd_newton`; libigl has no convergence test: it always runs ``iterations``.

    Returns
    -------
    X : (n,3) numpy array
    """
    import igl

    V = np.ascontiguousarray(V, dtype=float)
    T = np.ascontiguousarray(T, dtype=np.int64)
    b = np.ascontiguousarray(handles, dtype=np.int64)
    bc = np.ascontiguousarray(targets, dtype=float)
    data = igl.ARAPData()
    data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
    data.max_iter = int(iterations)
    igl.arap_precomputation(V, T, 3, b, data)
    U0 = np.array(V if X0 is None else X0, dtype=float)
    U0[b] = bc
    return np.asarray(igl.arap_solve(bc, data, U0))

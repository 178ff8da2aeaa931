"""The rivals libigl computes: bounded biharmonic weights + LBS, biharmonic coordinates, ARAP iterations.

- BBW + LBS: Jacobson, Baran, Popović & Sorkine 2011 (libigl ``bbw``), translations only; X = V + W (Q − P).
- Biharmonic coordinates: Wang, Jacobson et al. 2015 (libigl ``biharmonic_coordinates``); X = W Q.
- ARAP iterations: Sorkine & Alexa 2007 (libigl ``arap_solve``); k local-global steps per frame.

libigl takes tets as they are (``arap_precomputation`` with dim 3, ``bbw`` and ``biharmonic_coordinates`` on
tets). ARAP in 3D refuses handles on one line (a rotation about it is free), with the solver's own rule
(:func:`defop.variational.problem.check_handle_span`).
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from ..variational import problem
from .checks import check_positions, check_span, mesh_arrays

__all__ = ["ARAPIterations", "bbw_precompute", "biharmonic_precompute", "lbs_evaluate"]


def bbw_precompute(mesh, handles, max_iter=100):
    """Bounded biharmonic weights (Jacobson et al. 2011) of point handles, rows normalised to sum 1.

    Minimises Σ_i ∫ (Δw_i)² subject to w_i(p_j) = δ_ij, 0 ≤ w_i ≤ 1 (libigl ``bbw``, active set). With
    translations only, linear blend skinning is X = V + W (Q − P).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices.
    max_iter : int

    Returns
    -------
    W : (n,h) numpy array
    """
    import igl

    max_iter = opt.integer("max_iter", max_iter, minimum=1)  # libigl took 0 or -1 as its own default
    V, F, b = mesh_arrays(mesh, handles)
    bc = np.eye(len(b))
    W = np.asarray(igl.bbw(V, F, b, bc, max_iter=max_iter))
    return W / W.sum(axis=1, keepdims=True)


def lbs_evaluate(V, W, P, Q):
    """Linear blend skinning with translations only: X = V + W (Q − P).

    Parameters
    ----------
    V : (n,d) numpy array
    W : (n,h) numpy array
    P, Q : (h,d) numpy array

    Returns
    -------
    X : (n,d) numpy array
    """
    return V + W @ (check_positions(Q, W.shape[1], np.shape(V)[-1]) - P)


def biharmonic_precompute(mesh, handles, k=2):
    """Biharmonic coordinates (Wang, Jacobson et al. 2015; libigl ``biharmonic_coordinates``).

    Linearly precise coordinates W minimising the k-harmonic energy with the handles as the only
    constraints: X = W Q, and W P = V. On triangles (d = 2) or tetrahedra (d = 3).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices, at least d + 1 (libigl returns an empty matrix for fewer), spanning R^d.
    k : int
        2 for biharmonic (1 harmonic, 4 tetraharmonic). libigl 2.6.3 returns an empty matrix for k = 3
        (triharmonic) on every mesh and handle set tried (3 to 40 handles on the bar): refused with a message.

    Returns
    -------
    W : (n,h) numpy array

    Raises
    ------
    ValueError
        Fewer than d + 1 handles, handles all on one line in 2D or one plane in 3D (no linear precision:
        W P = V has no solution), k = 3
        or k not a positive integer, or libigl returning no coordinates.
    """
    import igl

    k = opt.integer("k", k, minimum=1)
    if k == 3:
        raise ValueError(
            "k = 3 (triharmonic) is not available: libigl's biharmonic_coordinates returns an empty "
            "matrix for k = 3; use k = 2 (biharmonic)"
        )
    V, F, b = mesh_arrays(mesh, handles)
    d = V.shape[1]
    if len(b) < d + 1:
        raise ValueError(f"biharmonic coordinates need at least {d + 1} point handles (linear precision), got {len(b)}")
    check_span(V[b], d, "biharmonic coordinates need", "linear precision: W P = V")
    W = np.asarray(igl.biharmonic_coordinates(V, F, [[int(i)] for i in b], int(k)))
    if W.shape != (len(V), len(b)) or not np.isfinite(W).all():
        raise ValueError(f"libigl biharmonic_coordinates failed (returned shape {W.shape})")
    return W


class ARAPIterations:
    """k local-global ARAP iterations per frame (libigl), warm-started from the previous frame.

    libigl's ``arap_solve`` has no convergence test: it always runs ``iterations`` steps. It minimises
    Σ_t A_t ‖J_t − R_t‖²_F (Sorkine & Alexa 2007, per element: triangle areas in 2D, tet volumes in 3D with
    ``arap_precomputation``'s dim 3), the ARAP energy (10), and may invert elements. In 3D the handles must not
    all lie on one line (:func:`defop.variational.problem.check_handle_span`: a rotation about it is free).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
    iterations : int
    """

    def __init__(self, mesh, handles, iterations=10):
        import igl

        self._V, F, self._b = mesh_arrays(mesh, handles)
        problem.check_handle_span(mesh, self._b)
        self._F = F  # libigl keeps references: hold the arrays
        self.iterations = opt.integer("iterations", iterations, minimum=1)
        self.data = igl.ARAPData()
        self.data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
        self.data.max_iter = self.iterations
        igl.arap_precomputation(self._V, self._F, self._V.shape[1], self._b, self.data)
        self.reset()

    def reset(self):
        """Start the next frame from the rest pose."""
        self.U = self._V.copy()

    def __call__(self, Q):
        """(n,d) positions after ``iterations`` steps from the previous frame, handles at Q (h,d)."""
        import igl

        Q = np.ascontiguousarray(check_positions(Q, len(self._b), self._V.shape[1]))
        U = np.ascontiguousarray(self.U)
        U[self._b] = Q
        self.U = np.array(igl.arap_solve(Q, self.data, U))
        return self.U.copy()

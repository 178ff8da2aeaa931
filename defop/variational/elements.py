"""The element kernels of problem (6): E, ∇E and the projected Hessian of one energy on one mesh.

Two implementations of the same sums over elements (Eqs. 10-11 and the isometric energies through the singular values
of each Jacobian): "numba", one fused compiled loop per call (:mod:`defop.variational.fused`: energy, gradient and the
projected Hessian scattered straight into the CSC values), and "numpy", the closed forms of
:mod:`defop.variational.energies`, kept as the reference. Both give the same values to round-off
(``tests/test_fused_kernel.py``). :class:`defop.variational.problem.ReducedProblem` holds one :class:`ElementKernels`.
"""

from __future__ import annotations

import os

import numpy as np

from . import energies as en

#: the element kernels of E, ∇E and the Hessian: "numba" (fused, :mod:`defop.variational.fused`; where it has the
#: energy) or "numpy" (the closed forms of :mod:`defop.variational.energies`, the reference); ``DEFOP_KERNEL``
KERNELS = ("numba", "numpy")


def check_kernel(kernel):
    """A kernel of :data:`KERNELS` (None: ``DEFOP_KERNEL``, else "numba"), or a ValueError naming it."""
    if kernel is None:
        kernel = os.environ.get("DEFOP_KERNEL", "").strip() or "numba"
        if kernel not in KERNELS:
            raise ValueError(f"DEFOP_KERNEL must be one of {', '.join(KERNELS)}, got {kernel!r}")
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
    return kernel


class ElementKernels:
    """E, ∇E and the projected Hessian of one energy on one mesh, by the fused kernels or the numpy path.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        V (n, d), F (m, d + 1).
    energy : str
        One of :data:`defop.variational.energies.ENERGIES` (checked by the caller).
    hessian : defop.variational.problem.ReducedHessian
        The fixed sparsity pattern the Hessian values are assembled into.
    kernel : str, optional
        One of :data:`KERNELS` (default ``DEFOP_KERNEL``, else ``"numba"``).
    """

    def __init__(self, mesh, energy, hessian, kernel=None):
        self.mesh, self.energy, self.hessian = mesh, energy, hessian
        self.kernel = kernel
        self._order = None

    def __getstate__(self):
        return {**self.__dict__, "_order": None}

    @property
    def kernel(self) -> str:
        """The kernel in use, "numba" or "numpy" (:data:`KERNELS`); setting it switches the Hessian's assembly too."""
        return self._kernel

    @kernel.setter
    def kernel(self, kernel):
        self._kernel = self.hessian.kernel = check_kernel(kernel)

    def jacobians(self, X):
        """(m, d, d) Jacobians of the map X (n, d), from the mesh's sparse operator."""
        d = self.mesh.dim
        return (self.mesh.jacobian_operator @ np.asarray(X, dtype=float).ravel()).reshape(-1, d, d)

    def _fused(self):
        """The fused kernels' module and this energy's code, or None where the numpy path runs."""
        if self.kernel != "numba":
            return None
        from . import fused

        code = fused.CODES.get(self.energy)
        return None if code is None or self.mesh.dim not in fused.DIMS else (fused, code)

    def _vertex_order(self, fused):
        """Each element's vertices in the fused kernels' order of summation (``fused.vertex_order``)."""
        if self._order is None:
            self._order = fused.vertex_order(self.mesh.F)
        return self._order

    def _map(self, X):
        """X as a C-contiguous float (n, d) array; ValueError (as ``Mesh.jacobians``) on another shape."""
        X = np.ascontiguousarray(X, dtype=float)
        if X.shape != self.mesh.V.shape:
            raise ValueError(f"X must have shape {self.mesh.V.shape}, got {X.shape}")
        return X

    def energies(self, X, mu):
        """(E_μ(X), E(X)): the smoothed energy Newton minimises and the true one, from one SVD."""
        fk = self._fused()
        if fk is not None:
            mesh = self.mesh
            args = (mesh.F, mesh.local_gradients, self._vertex_order(fk[0]), mesh.areas, fk[1], float(mu))
            return fk[0].energies(self._map(X), *args)
        if not mu:
            E = en.total_energy(self.mesh, X, self.energy)
            return E, E
        smooth, exact = en.density(self.mesh.jacobians(X), self.energy, mu, both=True)
        return float(self.mesh.areas @ smooth), float(self.mesh.areas @ exact)

    def grad_hess(self, X, mu=0.0, project=True, kink=0.0):
        """E, the gradient (d·n,) and the Hessian values in the fixed upper-triangular CSC pattern.

        Per element, K_t = A_t Σ_k λ_k w_k w_kᵀ with w_k = B_tᵀ vec(M_k) for the eigenpairs (λ_k, M_k)
        of :func:`defop.variational.energies.eigensystem`: no d²×d² Hessian is formed. Also returns ``local``,
        with which :meth:`ReducedHessian.assemble` rebuilds the projected Hessian without a second eigensystem.
        With the "numba" kernel, one fused loop over the elements (:func:`defop.variational.fused.grad_hess`).
        """
        fk = self._fused()
        if fk is not None:
            return self._grad_hess_fused(fk, X, mu, project, kink)
        mesh = self.mesh
        G = mesh.jacobian_operator
        J = self.jacobians(X)
        psi, grad, lam, modes = en.eigensystem(J, self.energy, project=False, mu=mu, kink=kink)
        A = mesh.areas
        E = float(A @ psi)
        g = G.T @ (A[:, None] * grad).ravel()
        D = mesh.local_gradients  # (m, d+1, d)
        m, d, k = len(D), J.shape[-1], modes.shape[-1]
        # w_k[d·i+a] = Σ_b ∇φ_i[b] M_k[a,b]: one (d+1, d) @ (d, d·k) product per element
        Mb = np.ascontiguousarray(modes.reshape(m, d, d, k).transpose(0, 2, 1, 3)).reshape(m, d, d * k)
        local = (np.matmul(D, Mb).reshape(m, (d + 1) * d, k), lam * A[:, None])
        return E, g, self.hessian.assemble(local, project), local

    def _grad_hess_fused(self, fk, X, mu, project, kink):
        """:meth:`grad_hess` by :func:`defop.variational.fused.grad_hess`."""
        fused, code = fk
        mesh, H, d = self.mesh, self.hessian, self.mesh.dim
        m = len(mesh.F)
        kink = np.asarray(kink, dtype=float)
        hold = bool(self.energy == "sarap" and mu == 0 and np.any(kink > 0))
        kink = np.ascontiguousarray(np.broadcast_to(kink[:, None] if kink.ndim == 1 else kink, (m, 2)))
        g, data = np.empty(d * len(mesh.V)), np.empty(H.nnz)
        W, lamA = np.empty((m, (d + 1) * d, d * d)), np.empty((m, d * d))
        args = (mesh.F, mesh.local_gradients, self._vertex_order(fused), mesh.areas, code, float(mu), kink, hold)
        E = fused.grad_hess(self._map(X), *args, bool(project), H.slot, g, data, W, lamA)
        return E, g, data, (W, lamA)

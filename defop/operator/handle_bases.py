"""Handle bases Ψ (§3.1): functions on R^{dn} of the moving handles' positions Q (n,d), d = 2 or 3.

Fixed handles are not variables. Every basis is evaluated on the normalised displacement
z = (Q − P).ravel() / scale ∈ R^{dn} (P the rest positions of the moving handles), which keeps the
small systems of the fit well conditioned. Its first 1 + dn functions are always 1, z_1, ..., z_dn,
so an operator can reproduce the handles' own (linear) motion exactly (Proposition 2). The dimension d
is read from P (``P.shape[1]``).

| basis | size (d = 2) | size (any d) |
|---|---|---|
| linear | 2n + 1 | dn + 1 |
| quadratic | 1 + 3n + 2n² | C(dn + 2, 2) |
| cubic | C(2n+3, 3) | C(dn + 3, 3) |
| radial (``"tps"``) | 1 + 2n + m | 1 + dn + m |

The radial basis adds φ(‖z − c_k‖) centred at each training sample Q_k (m centres); with more functions
than samples, the fit adds the usual side conditions: the RBF weights sum to zero and are orthogonal to
the linear part (:meth:`TPSBasis.side_conditions`). The kernel φ depends on d (:data:`KERNELS`):

See :mod:`defop.operator.radial` for why r³ in 3D.
"""

from __future__ import annotations

import itertools
import numbers
from math import comb

import numpy as np

from .core import check_configurations
from .radial import KERNELS, cubic_kernel, cubic_phi, first_duplicate, radial_kernel, tps_kernel, tps_phi  # noqa: F401

KINDS = ("linear", "quadratic", "cubic", "tps")
DIMS = (2, 3)
#: limits of the polynomial bases (checked before the monomials are built: a file or a caller asking for more
#: gets a ValueError, not a MemoryError)
MAX_DEGREE = 8
MAX_SIZE = 250_000


class HandleBasis:
    """Base class: z-normalisation and validation.

    Parameters
    ----------
    P : (n,d) numpy array
        Rest positions of the moving handles, d = 2 or 3.
    scale : float
        Length that normalises displacements (default 1).
    """

    kind = "base"

    def __init__(self, P, scale=1.0):
        P = np.asarray(P, dtype=float)
        if P.ndim != 2 or P.shape[1] not in DIMS or len(P) == 0:
            raise ValueError(f"P must have shape (n,d) with n >= 1 and d = 2 or 3, got {P.shape}")
        if not np.isfinite(P).all():
            raise ValueError("P has NaN or infinite entries")
        if not np.isfinite(scale) or scale <= 0:
            raise ValueError(f"scale must be positive, got {scale!r}")
        self.P = P
        self.scale = float(scale)

    @property
    def n_handles(self) -> int:
        return len(self.P)

    @property
    def d(self) -> int:
        """Dimension of the space the handles move in (2 or 3)."""
        return self.P.shape[1]

    @property
    def dim(self) -> int:
        """dn, the dimension of the handle space."""
        return self.P.size

    def z(self, Q):
        """Normalised displacements (…, dn) of Q (n,d) or (k,n,d)."""
        Q = check_configurations(Q, self.n_handles, self.d)
        return ((Q - self.P) / self.scale).reshape(*Q.shape[:-2], self.dim)

    def __call__(self, Q):
        """Ψ(Q): (|Ψ|,) for Q (n,d), (k,|Ψ|) for Q (k,n,d)."""
        z = self.z(Q)
        out = self.evaluate_z(np.atleast_2d(z))
        return out[0] if z.ndim == 1 else out

    def evaluate_one(self, z):
        """Ψ at one normalised configuration z (dn,), without validation: the interactive fast path.

        Returns
        -------
        psi : (|Ψ|,) numpy array
        """
        return self.evaluate_z(z[None])[0]

    def delta_z(self, z):
        """δψ(z) = Ψ(z)[1:] − Ψ(0)[1:]: the basis relative to the rest pose, without the constant.

        The constant function drops out of every difference, and at the rest pose (z = 0, bit for bit,
        as z = (Q − P)/scale gives at Q = P) δψ is exactly zero in floating point: the same function of
        the same input, subtracted. :class:`defop.operator.DefOp` evaluates D(·, Q) = x + δψ(Q) W[1:].

        Parameters
        ----------
        z : (k,dn) numpy array

        Returns
        -------
        dpsi : (k,|Ψ|−1) numpy array
        """
        out = self.evaluate_z(z)[:, 1:]
        out -= self._rest()
        return out

    def delta_one(self, z):
        """:meth:`delta_z` at one configuration z (dn,), without validation. Returns (|Ψ|−1,)."""
        out = self.evaluate_one(z)[1:]
        out -= self._rest()
        return out

    def delta_raw(self, dz, zz, out):
        """δψ up to a fixed column scaling, from the raw displacement dz = (Q − P).ravel(): the fast paths.

        δψ(z) = :meth:`delta_raw` · :attr:`raw_scale` (column-wise), with z = dz / scale. A fast path
        folds ``raw_scale`` into its coefficient matrix once, so no frame pays for the scaling. Exactly
        zero at dz = 0 (bit for bit), as :meth:`delta_z`. No validation: the caller checks dz and zz.

        Parameters
        ----------
        dz : (dn,) or (k,dn) numpy array
        zz : float or (k,) numpy array
            |dz|² (row-wise).
        out : (|Ψ|−1,) or (k,|Ψ|−1) numpy array
            Written (float32 or float64; the values are cast on the last operation).

        Returns
        -------
        out : numpy array
        """
        if np.ndim(dz) == 1:
            out[...] = self.delta_one(dz / self.scale)
        else:
            out[...] = self.delta_z(dz / self.scale)
        return out

    @property
    def raw_scale(self):
        """(|Ψ|−1,) column scaling of :meth:`delta_raw` (ones for the polynomial bases)."""
        return np.ones(self.size - 1)

    def raw_bound(self, R):
        """An upper bound on max |delta_raw(dz)| over |dz| ≤ R (the fast paths' overflow guard).

        Polynomials: a monomial of degree g is at most max(1, R/scale)^g in magnitude.
        """
        degree = getattr(self, "degree", 1)
        return max(1.0, R / self.scale) ** degree

    def _rest(self):
        """Ψ(0)[1:], computed once by the same code path as every evaluation."""
        if getattr(self, "_psi0", None) is None:
            self._psi0 = self.evaluate_one(np.zeros(self.dim))[1:].copy()
        return self._psi0

    def side_conditions(self):
        """Linear conditions T c = 0 on coefficient vectors c (|Ψ|,); none for polynomials.

        Returns
        -------
        T : (s,|Ψ|) numpy array
        """
        return np.zeros((0, self.size))

    def linear_coefficients(self, handle, coord):
        """Coefficients of the function Q ↦ Q[handle, coord] (exactly representable).

        Parameters
        ----------
        handle : int
            Moving-handle index.
        coord : int
            0 for x, 1 for y, 2 for z (d = 3).

        Returns
        -------
        c : (|Ψ|,) numpy array
        """
        c = np.zeros(self.size)
        c[0] = self.P[handle, coord]
        c[1 + self.d * handle + coord] = self.scale
        return c

    def min_samples(self) -> int:
        """The fewest training samples (rest pose included) the fit needs with this basis."""
        return self.size

    def params(self):
        """What is needed to rebuild the basis (for saving)."""
        return {"kind": self.kind, "P": self.P, "scale": self.scale}


class PolynomialBasis(HandleBasis):
    """All monomials of z up to ``degree`` (degree 1 = linear).

    Parameters
    ----------
    P : (n,d) numpy array
    degree : int
        1, 2 or 3 (any positive integer up to :data:`MAX_DEGREE`, with at most :data:`MAX_SIZE` monomials).
    scale : float
    """

    def __init__(self, P, degree=1, scale=1.0):
        super().__init__(P, scale)
        ok = isinstance(degree, numbers.Real) and not isinstance(degree, bool) and np.isfinite(degree)
        if not ok or int(degree) != degree or degree < 1:
            raise ValueError(f"degree must be a positive integer, got {degree!r}")
        if degree > MAX_DEGREE:
            raise ValueError(f"degree must be at most {MAX_DEGREE}, got {degree!r}")
        if comb(self.dim + int(degree), int(degree)) > MAX_SIZE:
            size = comb(self.dim + int(degree), int(degree))
            raise ValueError(f"degree {degree} on R^{self.dim} has {size} monomials, limit |Ψ| <= {MAX_SIZE}")
        self.degree = int(degree)
        d = self.dim
        self.monomials = [()] + [
            m for deg in range(1, self.degree + 1) for m in itertools.combinations_with_replacement(range(d), deg)
        ]
        self.kind = {1: "linear", 2: "quadratic", 3: "cubic"}.get(self.degree, f"degree{self.degree}")
        # evaluation plan: each monomial of degree >= 2 = an earlier monomial times one coordinate
        index = {m: i for i, m in enumerate(self.monomials)}
        self._parent = np.array([index[m[:-1]] if len(m) > 1 else 0 for m in self.monomials[1:]])
        self._factor = np.array([m[-1] for m in self.monomials[1:]])
        # the same plan vectorised by degree: the monomials of degree d are contiguous, parents of lower degree
        deg = np.array([len(m) for m in self.monomials])
        self._by_degree = [
            (
                slice(int(np.argmax(deg == g)), int(np.argmax(deg == g)) + int(np.sum(deg == g))),
                self._parent[deg[1:] == g],
                self._factor[deg[1:] == g],
            )
            for g in range(1, self.degree + 1)
        ]

    @property
    def size(self) -> int:
        return comb(self.dim + self.degree, self.degree)

    def evaluate_z(self, z):
        k = len(z)
        out = np.empty((k, self.size))
        out[:, 0] = 1.0
        for cols, parent, factor in self._by_degree:  # one vectorised step per degree, parents first
            out[:, cols] = out[:, parent] * z[:, factor]
        return out

    def params(self):
        return {**super().params(), "degree": self.degree}


class LinearBasis(PolynomialBasis):
    """1, z (size dn + 1)."""

    def __init__(self, P, scale=1.0):
        super().__init__(P, 1, scale)

    def evaluate_z(self, z):
        return np.column_stack([np.ones(len(z)), z])


class TPSBasis(HandleBasis):
    """Radial basis on R^{dn}: 1, z, and φ(‖z − c_k‖) at each centre c_k.

    φ(r) = r² log r (thin-plate spline) for d = 2, φ(r) = r³ (polyharmonic, conditionally positive
    definite of order 2) for d = 3: see the module docstring and :data:`KERNELS`.

    Parameters
    ----------
    P : (n,d) numpy array
    centers : (m,n,d) numpy array
        The training samples Q_k (the rest pose P included, as the fit does).
    scale : float

    Raises
    ------
    ValueError
        Duplicate centres, or centres of the wrong shape.
    """

    kind = "tps"

    def __init__(self, P, centers, scale=1.0):
        super().__init__(P, scale)
        self.kernel = KERNELS[self.d]
        self._phi = tps_phi if self.kernel == "r2logr" else cubic_phi
        C = check_configurations(centers, self.n_handles, self.d)
        if C.ndim != 3:
            raise ValueError(f"centers must have shape (m, {self.n_handles}, {self.d}), got {C.shape}")
        self.centers = C
        self._cz = self.z(C)  # (m, dn)
        dup = first_duplicate(self._cz, 1e-12)
        if dup is not None:
            i, j = dup
            raise ValueError(
                f"duplicate TPS centres {i} and {j} (0-based): the same handle configuration; in a fit, centre 0 "
                f"is the rest pose P and centre c is the sample Q_k with k = c - 1 (0-based)"
            )
        self._cz_sq = np.sum(self._cz**2, axis=1)
        self._cz_m2 = -2.0 * self._cz
        # delta_raw: −2c/scale as (dn, m), 1/scale², |c|² + ε, and ℓ(0) by the same code as every frame. ε keeps
        # r² = |c|² − 2c·z + |z|² + ε positive: its rounding error is about 1e-15 (|z| + |c|)², which can reach
        # |z − c|² only for z within 1e-7 |c| of a centre, where ε = 1e-12 max(1, max|c|²) exceeds it 100-fold;
        # φ moves by ½ ε |log r²| ≲ 1e-10 (r² log r), or by 1.5 ε r ≲ 1e-11 (r³), far below the float32
        # rounding of the fast paths
        self._cz_sq_eps = self._cz_sq + 1e-12 * max(1.0, float(self._cz_sq.max()))
        self._cm = np.ascontiguousarray(self._cz_m2.T / self.scale)
        self._inv_s2 = 1.0 / (self.scale * self.scale)
        self._ell0 = 0.0
        self._ell0 = self.delta_raw(np.zeros(self.dim), 0.0, np.empty(self.size - 1))[self.dim :].copy()

    @property
    def size(self) -> int:
        return 1 + self.dim + len(self.centers)

    def evaluate_z(self, z):
        k, d = len(z), self.dim
        out = np.empty((k, self.size))
        out[:, 0] = 1.0
        out[:, 1 : 1 + d] = z
        r2 = z @ self._cz_m2.T  # −2 z·c, then + |z|² + |c|²
        r2 += np.einsum("ij,ij->i", z, z)[:, None]
        r2 += self._cz_sq
        self._phi(r2, out[:, 1 + d :])
        return out

    def evaluate_one(self, z):
        # one configuration: a matrix-vector product and one log over the centres, no batch temporaries
        out = np.empty(self.size)
        out[0] = 1.0
        out[1 : 1 + self.dim] = z
        r2 = self._cz_m2 @ z
        r2 += self._cz_sq
        r2 += z @ z
        self._phi(r2, out[1 + self.dim :])
        return out

    def delta_one(self, z):
        # the fast path of DefOp: z, then φ(‖z − c_k‖) − φ(‖c_k‖), in one buffer
        out = np.empty(self.size - 1)
        out[: self.dim] = z
        r2 = self._cz_m2 @ z
        r2 += self._cz_sq
        r2 += z @ z
        phi = out[self.dim :]
        self._phi(r2, phi)
        phi -= self._rest()[self.dim :]
        return out

    def delta_raw(self, dz, zz, out):
        """[dz, ℓ − ℓ(0)], r² = |z − c_k|²: δψ = [dz/scale, s(ℓ − ℓ(0))] with s the :attr:`raw_scale`.

        d = 2: ℓ = r² log r² = 2φ(r), s = ½ (exact). d = 3: ℓ = r² √r² = φ(r), s = 1.
        r² = |c|² − 2c·z + |z|² from one gemv (gemm for k rows) on dz with −2c/scale kept; at dz = 0
        every term but |c|² is an exact zero, so ℓ(0) (computed here at init) comes out of the same bits
        as a frame at rest and δψ(0) = 0 exactly. Four ufuncs after the product. r² carries the ε of
        ``_cz_sq_eps`` (see ``__init__``), so it is positive without a clamp.
        """
        r2 = np.dot(dz, self._cm)  # np.dot: less call overhead than @ for a vector
        r2 += self._cz_sq_eps
        r2 += (zz[:, None] if type(zz) is np.ndarray else zz) * self._inv_s2
        ell = np.log(r2) if self.kernel == "r2logr" else np.sqrt(r2)
        ell *= r2
        d = self.dim
        np.subtract(ell, self._ell0, out=out[..., d:])
        out[..., :d] = dz
        return out

    def raw_constants(self):
        """The constants of :meth:`delta_raw` for the compiled single frame (:func:`defop.operator.kernels.tps_raw`).

        Returns
        -------
        cm : (dn, m) numpy array
            −2c/scale.
        czeps : (m,) numpy array
            |c|² + ε.
        inv_s2 : float
            1/scale².
        log_kernel : bool
            True for ℓ = r² log r² (d = 2), False for ℓ = r² √r² (d = 3).
        """
        return self._cm, self._cz_sq_eps, self._inv_s2, self.kernel == "r2logr"

    @property
    def raw_scale(self):
        half = 0.5 if self.kernel == "r2logr" else 1.0
        return np.concatenate([np.full(self.dim, 1.0 / self.scale), np.full(len(self._cz), half)])

    def raw_bound(self, R):
        """|dz| ≤ R: |dz_i| ≤ R, r² ≤ (R/scale + max|c|)², |ℓ| ≤ max(r² |log r²|, 1/e) (d = 2) or r³ (d = 3),
        plus |ℓ(0)|."""
        r2 = (R / self.scale + np.sqrt(self._cz_sq.max())) ** 2 + float(self._cz_sq_eps.max())
        if self.kernel == "r2logr":
            ell = max(r2 * abs(np.log(max(r2, 1e-300))), 1 / np.e)
        else:
            ell = r2 * np.sqrt(r2)
        return max(R, ell + float(np.abs(self._ell0).max()))

    def side_conditions(self):
        """Σ_k w_k = 0 and Σ_k w_k c_k = 0 for the RBF weights w (the linear part is unconstrained).

        Returns
        -------
        T : (1+dn, |Ψ|) numpy array
        """
        m = len(self.centers)
        T = np.zeros((1 + self.dim, self.size))
        T[:, 1 + self.dim :] = np.column_stack([np.ones(m), self._cz]).T
        return T

    def min_samples(self) -> int:
        return self.dim + 2

    def params(self):
        return {**super().params(), "centers": self.centers, "kernel": self.kernel}


def make_basis(kind, P, centers=None, scale=1.0):
    """Build Ψ by name.

    Parameters
    ----------
    kind : str
        ``"linear"``, ``"quadratic"``, ``"cubic"`` or ``"tps"``.
    P : (n,d) numpy array
        Rest positions of the moving handles.
    centers : (m,n,d) numpy array
        TPS centres (the training samples); required for ``"tps"``.
    scale : float

    Returns
    -------
    basis : HandleBasis
    """
    if kind == "linear":
        return LinearBasis(P, scale)
    if kind == "quadratic":
        return PolynomialBasis(P, 2, scale)
    if kind == "cubic":
        return PolynomialBasis(P, 3, scale)
    if kind == "tps":
        if centers is None:
            raise ValueError("the TPS basis needs centers: the training samples Q_k, shape (m, n, d)")
        return TPSBasis(P, centers, scale)
    raise ValueError(f"unknown handle basis {kind!r}; known: {', '.join(KINDS)}")


def basis_size(kind, n, m=None, d=2):
    """|Ψ| for n moving handles in R^d (and m TPS centres).

    Returns
    -------
    size : int
        dn + 1 (linear), C(dn + 2, 2) (quadratic; 1 + 3n + 2n² for d = 2), C(dn + 3, 3) (cubic),
        1 + dn + m (tps).
    """
    if kind == "linear":
        return d * n + 1
    if kind == "quadratic":
        return comb(d * n + 2, 2)
    if kind == "cubic":
        return comb(d * n + 3, 3)
    if kind == "tps":
        return 1 + d * n + m
    raise ValueError(f"unknown handle basis {kind!r}; known: {', '.join(KINDS)}")

"""Handle bases Ψ (§3.1): functions on R^{2n} of the moving handles' positions Q (n,2).

Fixed handles are not variables. Every basis is evaluated on the normalised displacement
z = (Q − P).ravel() / scale ∈ R^{2n} (P the rest positions of the moving handles), which keeps the
small systems of the fit well conditioned. Its first 1 + 2n functions are always 1, z_1, ..., z_2n,
so an operator can reproduce the handles' own (linear) motion exactly (Proposition 2).

| basis | size |
|---|---|
| linear | 2n + 1 |
| quadratic | 1 + 3n + 2n² |
| cubic | C(2n+3, 3) |
| thin-plate spline (TPS) | 1 + 2n + m |

The TPS basis adds r² log r centred at each training sample Q_k (m centres); with more functions than
samples, the fit adds the usual side conditions: the RBF weights sum to zero and are orthogonal to the
linear part (:meth:`TPSBasis.side_conditions`).
"""

from __future__ import annotations

import itertools
from math import comb

import numpy as np

KINDS = ("linear", "quadratic", "cubic", "tps")


def _check_Q(Q, n):
    if np.iscomplexobj(Q):  # float() would drop the imaginary part with only a ComplexWarning
        raise ValueError("Q must be real; got a complex array")
    Q = np.asarray(Q, dtype=float)
    if Q.ndim not in (2, 3) or Q.shape[-2:] != (n, 2):
        raise ValueError(f"Q must have shape ({n}, 2) or (k, {n}, 2) for {n} moving handles, got {Q.shape}")
    if not np.isfinite(Q).all():
        where = np.argwhere(~np.isfinite(Q))[0].tolist()
        raise ValueError(f"Q has NaN or infinite entries (first at {where}): {np.array2string(Q, threshold=20)}")
    return Q


class HandleBasis:
    """Base class: z-normalisation and validation.

    Parameters
    ----------
    P : (n,2) numpy array
        Rest positions of the moving handles.
    scale : float
        Length that normalises displacements (default 1).
    """

    kind = "base"

    def __init__(self, P, scale=1.0):
        P = np.asarray(P, dtype=float)
        if P.ndim != 2 or P.shape[1] != 2 or len(P) == 0:
            raise ValueError(f"P must have shape (n,2) with n >= 1, got {P.shape}")
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
    def dim(self) -> int:
        """2n, the dimension of the handle space."""
        return 2 * len(self.P)

    def z(self, Q):
        """Normalised displacements (…, 2n) of Q (n,2) or (k,n,2)."""
        Q = _check_Q(Q, self.n_handles)
        return ((Q - self.P) / self.scale).reshape(*Q.shape[:-2], self.dim)

    def __call__(self, Q):
        """Ψ(Q).

        Parameters
        ----------
        Q : (n,2) or (k,n,2) numpy array

        Returns
        -------
        psi : (|Ψ|,) or (k,|Ψ|) numpy array
        """
        z = self.z(Q)
        out = self.evaluate_z(np.atleast_2d(z))
        return out[0] if z.ndim == 1 else out

    def evaluate_one(self, z):
        """Ψ at one normalised configuration z (2n,), without validation: the interactive fast path.

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
        z : (k,2n) numpy array

        Returns
        -------
        dpsi : (k,|Ψ|−1) numpy array
        """
        out = self.evaluate_z(z)[:, 1:]
        out -= self._rest()
        return out

    def delta_one(self, z):
        """:meth:`delta_z` at one configuration z (2n,), without validation. Returns (|Ψ|−1,)."""
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
        dz : (2n,) or (k,2n) numpy array
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
            0 for x, 1 for y.

        Returns
        -------
        c : (|Ψ|,) numpy array
        """
        c = np.zeros(self.size)
        c[0] = self.P[handle, coord]
        c[1 + 2 * handle + coord] = self.scale
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
    P : (n,2) numpy array
    degree : int
        1, 2 or 3 (any positive integer works).
    scale : float
    """

    def __init__(self, P, degree=1, scale=1.0):
        super().__init__(P, scale)
        if int(degree) != degree or degree < 1:
            raise ValueError(f"degree must be a positive integer, got {degree!r}")
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
    """1, z (size 2n + 1)."""

    def __init__(self, P, scale=1.0):
        super().__init__(P, 1, scale)

    def evaluate_z(self, z):
        return np.column_stack([np.ones(len(z)), z])


def _tps_phi(r2, out):
    """φ = r² log r = ½ r² log r² from squared distances ``r2`` (overwritten), written into ``out``."""
    r2[r2 <= 0] = 1.0  # at a centre (or rounded below 0): ½·1·log 1 = 0 = φ(0), exactly
    np.log(r2, out=out)
    out *= r2
    out *= 0.5


def tps_kernel(r):
    """φ(r) = r² log r with φ(0) = 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0, r * r * np.log(np.where(r > 0, r, 1.0)), 0.0)


class TPSBasis(HandleBasis):
    """Thin-plate splines on R^{2n}: 1, z, and φ(‖z − c_k‖) with φ(r) = r² log r at each centre c_k.

    Parameters
    ----------
    P : (n,2) numpy array
    centers : (m,n,2) numpy array
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
        C = _check_Q(centers, self.n_handles)
        if C.ndim != 3:
            raise ValueError(f"centers must have shape (m, {self.n_handles}, 2), got {C.shape}")
        self.centers = C
        self._cz = self.z(C)  # (m, 2n)
        d2 = np.sum((self._cz[:, None] - self._cz[None]) ** 2, axis=-1)
        dup = np.argwhere(np.triu(d2 <= (1e-12) ** 2, 1))
        if len(dup):
            i, j = dup[0]
            raise ValueError(
                f"duplicate TPS centres {i} and {j} (0-based): the same handle configuration; in a fit, centre 0 "
                f"is the rest pose P and centre c is the sample Q_k with k = c - 1 (0-based)"
            )
        self._cz_sq = np.sum(self._cz**2, axis=1)
        self._cz_m2 = -2.0 * self._cz
        # delta_raw: −2c/scale as (2n, m), 1/scale², |c|² + ε, and ℓ(0) by the same code as every frame. ε keeps
        # r² = |c|² − 2c·z + |z|² + ε positive: its rounding error is about 1e-15 (|z| + |c|)², which can reach
        # |z − c|² only for z within 1e-7 |c| of a centre, where ε = 1e-12 max(1, max|c|²) exceeds it 100-fold;
        # φ moves by ½ ε |log r²| ≲ 1e-10 (far below the float32 rounding of the fast paths)
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
        _tps_phi(r2, out[:, 1 + d :])
        return out

    def evaluate_one(self, z):
        # one configuration: a matrix-vector product and one log over the centres, no batch temporaries
        out = np.empty(self.size)
        out[0] = 1.0
        out[1 : 1 + self.dim] = z
        r2 = self._cz_m2 @ z
        r2 += self._cz_sq
        r2 += z @ z
        _tps_phi(r2, out[1 + self.dim :])
        return out

    def delta_one(self, z):
        # the fast path of DefOp: z, then φ(‖z − c_k‖) − φ(‖c_k‖), in one buffer
        out = np.empty(self.size - 1)
        out[: self.dim] = z
        r2 = self._cz_m2 @ z
        r2 += self._cz_sq
        r2 += z @ z
        phi = out[self.dim :]
        _tps_phi(r2, phi)
        phi -= self._rest()[self.dim :]
        return out

    def delta_raw(self, dz, zz, out):
        """[dz, ℓ − ℓ(0)] with ℓ = r² log r² = 2φ(r), r² = |z − c_k|²: δψ = [dz/scale, ½(ℓ − ℓ(0))] (raw_scale).

        r² = |c|² − 2c·z + |z|² from one gemv (gemm for k rows) on dz with −2c/scale kept; at dz = 0
        every term but |c|² is an exact zero, so ℓ(0) (computed here at init) comes out of the same bits
        as a frame at rest and δψ(0) = 0 exactly. Four ufuncs after the product; ×½ is exact. r² carries
        the ε of ``_cz_sq_eps`` (see ``__init__``), so it is positive without a clamp.
        """
        r2 = np.dot(dz, self._cm)  # np.dot: less call overhead than @ for a vector
        r2 += self._cz_sq_eps
        r2 += (zz[:, None] if type(zz) is np.ndarray else zz) * self._inv_s2
        ell = np.log(r2)
        ell *= r2
        d = self.dim
        np.subtract(ell, self._ell0, out=out[..., d:])
        out[..., :d] = dz
        return out

    @property
    def raw_scale(self):
        return np.concatenate([np.full(self.dim, 1.0 / self.scale), np.full(len(self._cz), 0.5)])

    def raw_bound(self, R):
        """|dz| ≤ R: |dz_i| ≤ R, r² ≤ (R/scale + max|c|)², |ℓ| ≤ max(r² |log r²|, 1/e), plus |ℓ(0)|."""
        r2 = (R / self.scale + np.sqrt(self._cz_sq.max())) ** 2 + float(self._cz_sq_eps.max())
        ell = max(r2 * abs(np.log(max(r2, 1e-300))), 1 / np.e)
        return max(R, ell + float(np.abs(self._ell0).max()))

    def side_conditions(self):
        """Σ_k w_k = 0 and Σ_k w_k c_k = 0 for the RBF weights w (the linear part is unconstrained).

        Returns
        -------
        T : (1+2n, |Ψ|) numpy array
        """
        m = len(self.centers)
        T = np.zeros((1 + self.dim, self.size))
        T[:, 1 + self.dim :] = np.column_stack([np.ones(m), self._cz]).T
        return T

    def min_samples(self) -> int:
        return self.dim + 2

    def params(self):
        return {**super().params(), "centers": self.centers}


def make_basis(kind, P, centers=None, scale=1.0):
    """Build Ψ by name.

    Parameters
    ----------
    kind : str
        ``"linear"``, ``"quadratic"``, ``"cubic"`` or ``"tps"``.
    P : (n,2) numpy array
        Rest positions of the moving handles.
    centers : (m,n,2) numpy array
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
            raise ValueError("the TPS basis needs centers: the training samples Q_k, shape (m, n, 2)")
        return TPSBasis(P, centers, scale)
    raise ValueError(f"unknown handle basis {kind!r}; known: {', '.join(KINDS)}")


def basis_size(kind, n, m=None):
    """|Ψ| for n moving handles (and m TPS centres).

    Returns
    -------
    size : int
    """
    if kind == "linear":
        return 2 * n + 1
    if kind == "quadratic":
        return 1 + 3 * n + 2 * n * n
    if kind == "cubic":
        return comb(2 * n + 3, 3)
    if kind == "tps":
        return 1 + 2 * n + m
    raise ValueError(f"unknown handle basis {kind!r}; known: {', '.join(KINDS)}")

"""The trained deformation operator DefOp: D(x, Q) = Σ_ij C_ij φ_i(x) ψ_j(Q) (Eq. 3).

After fitting, the spatial basis is folded into the coefficients: D(·, Q) as row-major vertex positions
is ``Ψ(Q) @ W`` with W (|Ψ| × 2n_vertices). One evaluation is a handle-basis evaluation plus one small
dense product. :meth:`DefOp.compress` replaces W by a truncated SVD factor ``W ≈ A B`` (|Ψ| × r, r × 2n),
which is what makes ≥ 20,000 evaluations per second possible; :meth:`DefOp.compression_error` measures
what it costs.
"""

from __future__ import annotations

import json
import warnings
import zipfile
from pathlib import Path

import numpy as np

from . import handle_bases as hb
from .mesh import Mesh

FORMAT = "defop-operator-1"


class ExtrapolationWarning(UserWarning):
    """A handle configuration far outside the sampled region: the operator extrapolates."""


class DefOp:
    """A trained closed-form deformation operator.

    Parameters
    ----------
    mesh : defop.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices of all handles.
    moving : (h,) bool numpy array
    handle_basis : defop.handle_bases.HandleBasis
        Ψ, a function of the moving handles.
    W : (|Ψ|, 2 n_vertices) numpy array
        Folded coefficients: D(·, Q).ravel() = Ψ(Q) @ W.
    meta : dict, optional
        Shape, energy, bases, number of samples, library version.
    train_samples : (m,n,2) numpy array, optional
        The training configurations (for the extrapolation warning).

    Attributes
    ----------
    P : (n,2) numpy array
        Rest positions of the moving handles.
    """

    def __init__(self, mesh, handles, moving, handle_basis, W, meta=None, train_samples=None):
        self.mesh = mesh
        self.handles = np.asarray(handles, dtype=np.int64)
        self.moving = np.asarray(moving, dtype=bool)
        self.handle_basis = handle_basis
        self.W = np.ascontiguousarray(W, dtype=float)
        self.factors = None  # (A, B) after compress()
        from . import __version__

        self.meta = {"version": __version__, **(meta or {})}
        self.train_samples = None if train_samples is None else np.asarray(train_samples, float)
        self._reach = None
        if self.train_samples is not None and len(self.train_samples) > 1:
            d = np.linalg.norm(self.train_samples - self.P, axis=-1)  # (m, n)
            self._reach = d.max(axis=0)
        self.fit_time = self.fold_time = None

    # ------------------------------------------------------------------ properties
    @property
    def P(self):
        """(n,2) rest positions of the moving handles."""
        return self.handle_basis.P

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @property
    def energy(self):
        return self.meta.get("energy")

    @property
    def n_samples(self):
        return self.meta.get("n_samples")

    @property
    def rank(self):
        """Rank of the compressed factor, or None when uncompressed."""
        return None if self.factors is None else self.factors[0].shape[1]

    def __repr__(self):
        comp = f", rank {self.rank}" if self.factors is not None else ""
        return (
            f"DefOp({self.meta.get('shape', '?')}, {self.meta.get('energy', '?')}, Ψ={self.handle_basis.kind} "
            f"|Ψ|={self.handle_basis.size}, Φ={self.meta.get('spatial', '?')}, "
            f"{self.n_samples} samples{comp})"
        )

    # ------------------------------------------------------------------ evaluation
    def _check_extrapolation(self, Q):
        if self._reach is None:
            return
        d = np.linalg.norm(Q - self.P, axis=-1)
        far = d > 1.5 * self._reach + 1e-12
        if np.any(far):
            idx = np.argwhere(far)[0]
            j = int(idx[-1])
            warnings.warn(
                f"moving handle {j} is {d[tuple(idx)]:.3g} from rest, beyond 1.5x the farthest training sample "
                f"({self._reach[j]:.3g}): the operator extrapolates",
                ExtrapolationWarning,
                stacklevel=3,
            )

    def psi(self, Q):
        """Ψ(Q): (|Ψ|,) or (k,|Ψ|)."""
        return self.handle_basis(Q)

    def __call__(self, Q):
        """D(·, Q): the deformed vertex positions.

        Parameters
        ----------
        Q : (n,2) or (k,n,2) numpy array
            Positions of the moving handles.

        Returns
        -------
        X : (n_vertices,2) or (k,n_vertices,2) numpy array

        Raises
        ------
        ValueError
            Q with the wrong shape or NaN.
        """
        Q = np.asarray(Q, dtype=float)
        psi = self.handle_basis(Q)  # validates shape and NaN
        self._check_extrapolation(Q)
        if self.factors is None:
            out = psi @ self.W
        else:
            A, B = self.factors
            out = ((psi.astype(A.dtype) @ A) @ B).astype(np.float64)
        return out.reshape(*Q.shape[:-2], self.n_vertices, 2)

    def evaluate_fast(self, Q):
        """D(·, Q) for one configuration without validation (for interactive loops).

        Parameters
        ----------
        Q : (n,2) numpy array

        Returns
        -------
        X : (n_vertices,2) numpy array
        """
        psi = self.handle_basis.evaluate_one(((Q - self.handle_basis.P) / self.handle_basis.scale).ravel())
        if self.factors is None:
            return (psi @ self.W).reshape(-1, 2)
        A, B = self.factors
        return ((psi.astype(A.dtype) @ A) @ B).astype(np.float64).reshape(-1, 2)

    # ------------------------------------------------------------------ compression
    def compress(self, rank=None, tol=1e-3, dtype=np.float32):
        """Replace W by a truncated SVD factor W ≈ A B for speed.

        Parameters
        ----------
        rank : int, optional
            Keep this many singular values.
        tol : float
            Without ``rank``: keep the fewest singular values whose discarded part is at most ``tol``
            times ‖W‖_F (relative).
        dtype : numpy dtype
            Storage of A and B. A frame is a matrix–vector product over B (rank × 2·n_vertices) that is
            memory-bound, so float32 halves its time (aleph: 42 → 21 µs); its rounding (~1e-7
            relative) is far below the truncation's. Results are returned in float64.

        Returns
        -------
        self : DefOp
        """
        U, s, Vt = np.linalg.svd(self.W, full_matrices=False)
        if rank is None:
            tail = np.sqrt(np.concatenate([np.cumsum((s**2)[::-1])[::-1][1:], [0.0]]))
            rank = int(np.argmax(tail <= tol * np.linalg.norm(s))) + 1
        rank = max(1, min(int(rank), len(s)))
        self.factors = (
            np.ascontiguousarray(U[:, :rank] * s[:rank], dtype=dtype),
            np.ascontiguousarray(Vt[:rank], dtype=dtype),
        )
        self.meta["rank"] = rank
        return self

    def decompress(self):
        """Go back to the exact folded W."""
        self.factors = None
        self.meta.pop("rank", None)
        return self

    # ------------------------------------------------------------------ checks
    def check_mesh(self, mesh):
        """Raise ValueError unless ``mesh`` is the mesh this operator was trained on."""
        if mesh.n_vertices != self.mesh.n_vertices or mesh.n_faces != self.mesh.n_faces:
            raise ValueError(
                f"this operator was trained on a mesh with {self.mesh.n_vertices} vertices and {self.mesh.n_faces} "
                f"triangles, not {mesh.n_vertices} and {mesh.n_faces}"
            )
        if not (np.array_equal(mesh.F, self.mesh.F) and np.allclose(mesh.V, self.mesh.V, rtol=0, atol=1e-12)):
            raise ValueError(
                "this operator was trained on a different mesh (same size, different vertices or triangles)"
            )

    # ------------------------------------------------------------------ I/O
    def save(self, path):
        """Save as .npz: arrays plus JSON metadata (exact round trip).

        Parameters
        ----------
        path : str or pathlib.Path
        """
        params = self.handle_basis.params()
        arrays = {
            "V": self.mesh.V,
            "F": self.mesh.F,
            "handles": self.handles,
            "moving": self.moving,
            "W": self.W,
            "basis_P": params["P"],
        }
        if "centers" in params:
            arrays["basis_centers"] = params["centers"]
        if self.train_samples is not None:
            arrays["train_samples"] = self.train_samples
        if self.factors is not None:
            arrays["factor_A"], arrays["factor_B"] = self.factors
        header = {
            "format": FORMAT,
            "meta": self.meta,
            "basis": {"kind": params["kind"], "scale": params["scale"], "degree": params.get("degree")},
        }
        arrays["header"] = np.array(json.dumps(header))
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)

    @classmethod
    def load(cls, path):
        """Load an operator written by :meth:`save`.

        Raises
        ------
        ValueError
            A missing, corrupt or incompatible file.
        """
        path = Path(path)
        if not path.exists():
            raise ValueError(f"no such operator file: {path}")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
            header = json.loads(str(data["header"]))
        except (zipfile.BadZipFile, OSError, EOFError, KeyError, json.JSONDecodeError, ValueError) as exc:
            raise ValueError(f"{path} is not a readable defop operator file ({type(exc).__name__}: {exc})") from exc
        if header.get("format") != FORMAT:
            raise ValueError(f"{path} has format {header.get('format')!r}; this defop reads {FORMAT!r}")
        need = {"V", "F", "handles", "moving", "W", "basis_P"}
        missing = need - set(data)
        if missing:
            raise ValueError(f"{path} is incomplete: missing {sorted(missing)}")
        b = header["basis"]
        kind = b["kind"]
        if kind == "tps":
            psi = hb.TPSBasis(data["basis_P"], data["basis_centers"], b["scale"])
        elif kind == "linear":
            psi = hb.LinearBasis(data["basis_P"], b["scale"])
        else:
            psi = hb.PolynomialBasis(data["basis_P"], b["degree"], b["scale"])
        mesh = Mesh(data["V"], data["F"])
        if data["W"].shape != (psi.size, 2 * mesh.n_vertices):
            raise ValueError(
                f"{path} is inconsistent: W has shape {data['W'].shape}, expected ({psi.size}, {2 * mesh.n_vertices})"
            )
        op = cls(mesh, data["handles"], data["moving"], psi, data["W"], header["meta"], data.get("train_samples"))
        op.meta = header["meta"]
        if "factor_A" in data:
            op.factors = (data["factor_A"], data["factor_B"])
        return op

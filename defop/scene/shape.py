"""The :class:`Shape`: a mesh of Ω with point handles, which of them move, and a sampling region per moving handle."""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import options as opt
from ..geometry.mesh import Mesh
from .handles import check_handles_span, handle_indices
from .regions import Region, as_region

__all__ = ["Shape"]


@dataclasses.dataclass(eq=False)
class Shape:
    """A mesh with point handles and sampling regions.

    Attributes
    ----------
    name : str
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices of all handles, moving and fixed.
    moving : (h,) bool numpy array
        Which handles move; Ψ is a function of the moving ones only.
    regions : list of defop.scene.regions.Region
        One sampling region per moving handle, in handle order, centred at its rest position
        (:mod:`defop.scene.regions`; dicts such as ``{"kind": "disc", "radius": r}`` are converted).
    description : str
    outline : list of (k,2) numpy array
        The polygon the mesh was made from (outer loop first); empty in 3D.
    surface : defop.geometry.volumetric.surface.EmbeddedSurface or None
        In 3D, the closed surface the tetrahedra were made from, embedded in them (for drawing).
    """

    name: str
    mesh: Mesh
    handles: np.ndarray
    moving: np.ndarray
    regions: list
    description: str = ""
    outline: list = dataclasses.field(default_factory=list)
    surface: object = None

    def __post_init__(self):
        n = self.mesh.n_vertices
        self.handles = handle_indices(self.handles, n)
        mv = np.asarray(self.moving).ravel()
        if mv.dtype != bool and not (np.issubdtype(mv.dtype, np.number) and np.isin(mv, (0, 1)).all()):
            raise ValueError(f"moving must be one True/False flag per handle, got {self.moving!r}")
        self.moving = mv.astype(bool)
        if len(self.moving) != len(self.handles):
            raise ValueError(f"moving has {len(self.moving)} entries for {len(self.handles)} handles")
        bad = np.flatnonzero((self.handles < 0) | (self.handles >= n))
        if len(bad):
            k = int(bad[0])
            raise ValueError(f"handle {k} is vertex {int(self.handles[k])}, but the mesh has {n} vertices")
        uniq, counts = np.unique(self.handles, return_counts=True)
        if (counts > 1).any():
            raise ValueError(f"vertex {int(uniq[counts > 1][0])} is given as a handle twice")
        if not self.moving.any():
            raise ValueError("a shape needs at least one moving handle")
        if isinstance(self.regions, (dict, Region)):
            self.regions = [self.regions]
        if len(self.regions) != self.n_moving:
            raise ValueError(f"{len(self.regions)} regions for {self.n_moving} moving handles")
        if self.mesh.dim == 3:
            check_handles_span(self.P)
        self.regions = [as_region(r, f"region {i}") for i, r in enumerate(self.regions)]

    @property
    def P(self):
        """(h,d) numpy array: rest positions of all handles."""
        return self.mesh.V[self.handles]

    @property
    def moving_handles(self):
        """(n,) int numpy array: vertex indices of the moving handles."""
        return self.handles[self.moving]

    @property
    def fixed_handles(self):
        """(h-n,) int numpy array: vertex indices of the fixed handles."""
        return self.handles[~self.moving]

    @property
    def P_moving(self):
        """(n,d) numpy array: rest positions p_l of the moving handles."""
        return self.mesh.V[self.moving_handles]

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    def targets(self, Q):
        """Positions of all handles for moved handles Q (fixed ones at rest).

        Parameters
        ----------
        Q : (n,d) numpy array
            Positions of the moving handles.

        Returns
        -------
        T : (h,d) numpy array
        """
        Q = opt.real_array("Q", Q)
        if Q.shape != (self.n_moving, self.mesh.dim):
            n, d = self.n_moving, self.mesh.dim
            raise ValueError(f"Q must have shape ({n}, {d}) for the {n} moving handles, got {Q.shape}")
        if not np.isfinite(Q).all():
            raise ValueError("Q has NaN or infinite entries")
        T = self.P.copy()
        T[self.moving] = Q
        return T

    def __repr__(self):
        return (
            f"Shape({self.name!r}, {self.mesh.n_vertices} vertices, {self.mesh.n_faces} "
            f"{'triangles' if self.mesh.dim == 2 else 'tetrahedra'}, "
            f"{self.n_moving} moving + {len(self.handles) - self.n_moving} fixed handles)"
        )

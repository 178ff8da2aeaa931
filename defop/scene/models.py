"""The paper's models as procedural outlines with default handles and sampling regions; 3D solids beyond it.

``bar`` (Fig. 3, 7), ``u_shape`` (Fig. 4), ``gingerbread`` (Fig. 6), ``aleph`` (Fig. 8, 9; the
letter א of DejaVu Sans through matplotlib's ``TextPath``), ``octopus`` (Fig. 1), ``crab`` (Fig. 2)
and ``dino`` (Table 1). Each model is a :class:`Model`: pure geometry (outline, holes, handle
points, moving flags, regions) that :func:`defop.scene.shapes.load` meshes. Organic outlines are unions
of tapered capsules and ellipses (:mod:`defop.geometry.planar.outlines`). Every coordinate is computed element-wise
(no BLAS), so the outline is the same on every CPU.

Beyond the paper, four solids (:class:`Solid`, meshed into tetrahedra by
:mod:`defop.geometry.volumetric`): ``bar_3d`` (a 1 × 0.2 × 0.2 beam with handle patches at both ends,
for the twist and bend of Fig. 7), ``plank_3d`` (1 × 0.2 × 0.4, clamped at one end, one handle on the other
end's centre: Fig. 10's buckling bar in 3D), ``octopus_3d`` (a head ellipsoid and eight tapered, waving arms:
an implicit union) and ``nut`` (a hexagonal nut modelled as a closed triangle surface, read from the
example data inside the installed PyVista wheel with libigl, without importing PyVista). They are
listed by ``names(dim=3)``; ``names()`` keeps listing the 2D catalogue.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..geometry.fields import ellipsoid
from ..geometry.planar.outlines import capsule, chain, cos_sin, ellipse, implicit_outline, union
from ..geometry.volumetric import mesher
from ..geometry.volumetric import surface as surfaces
from .regions import Disc, Ellipse, Mixture, Voronoi

ALEPH_OUTLINE = Path(__file__).with_name("data") / "aleph.json"


@dataclasses.dataclass
class Model:
    """Geometry of a named shape, before meshing.

    Attributes
    ----------
    name : str
    outer : (k,2) numpy array
    holes : list of (l,2) numpy array
    handles : (h,2) numpy array
        Handle positions (they become mesh vertices).
    moving : (h,) bool numpy array
    regions : list of defop.scene.regions.Region
        One per moving handle.
    description : str
    """

    name: str
    outer: np.ndarray
    holes: list
    handles: np.ndarray
    moving: np.ndarray
    regions: list
    description: str


def _bar():
    outer = np.array([[0, 0], [1, 0], [1, 0.2], [0, 0.2]], float)
    handles = [[0.96, 0.1], [0.02, 0.03], [0.02, 0.1], [0.02, 0.17]]
    return Model(
        "bar",
        outer,
        [],
        np.array(handles),
        np.array([True, False, False, False]),
        [Ellipse((0.06, 0.3))],
        "1 x 0.2 bar, left end clamped by 3 fixed handles, 1 moving handle at the right end (Fig. 3, 7); "
        "its region is a tall ellipse: pushing the end in by more than ~6% buckles the bar up or down (a jump)",
    )


def _u_shape():
    outer = np.array([[0, 0], [1, 0], [1, 1], [0.72, 1], [0.72, 0.3], [0.28, 0.3], [0.28, 1], [0, 1]], float)
    handles = [[0.14, 0.93], [0.86, 0.93], [0.1, 0.08], [0.5, 0.08], [0.9, 0.08], [0.5, 0.22]]
    return Model(
        "u_shape",
        outer,
        [],
        np.array(handles),
        np.array([True, True, False, False, False, False]),
        [Disc(0.2), Disc(0.2)],
        "U shape: the two arm tips move, the base is held by fixed handles (Fig. 4)",
    )


def _from_field(field, bbox, name, handles, moving, regions, description):
    outer, holes = implicit_outline(field, bbox)
    return Model(name, outer, holes, np.asarray(handles, float), np.asarray(moving, bool), regions, description)


def _gingerbread():
    f = union(
        ellipse((0, 0.78), 0.2, 0.2),  # head
        ellipse((0, 0.22), 0.26, 0.36),  # body
        capsule((-0.15, 0.42), (-0.55, 0.52), 0.11, 0.1),  # arms
        capsule((0.15, 0.42), (0.55, 0.52), 0.11, 0.1),
        capsule((-0.12, 0.0), (-0.3, -0.5), 0.13, 0.12),  # legs
        capsule((0.12, 0.0), (0.3, -0.5), 0.13, 0.12),
    )
    handles = [[-0.55, 0.52], [0.55, 0.52], [-0.3, -0.5], [0.3, -0.5], [0, 0.82]]
    return _from_field(
        f,
        [[-0.8, -0.75], [0.8, 1.1]],
        "gingerbread",
        handles,
        [True] * 5,
        [Disc(0.3)] * 5,
        "gingerbread man with handles at the hands, feet and head (Fig. 6)",
    )


# picked on the normalised DejaVu Sans glyph: the ends of the three strokes and the diagonal
_ALEPH_HANDLES = [[0.1, 0.95], [0.81, 0.93], [0.08, 0.05], [0.79, 0.05], [0.45, 0.5]]


def _aleph():
    # the glyph's outline, as matplotlib's TextPath gave it (data/aleph.json says how), bit for bit
    outer = np.array(json.loads(ALEPH_OUTLINE.read_text())["outline"], dtype=float)
    outer = (outer - outer.min(0)) / np.ptp(outer, axis=0).max()
    n = len(_ALEPH_HANDLES)
    return Model(
        "aleph",
        outer,
        [],
        np.array(_ALEPH_HANDLES),
        np.ones(n, bool),
        [Disc(0.12)] * n,
        "the Hebrew letter aleph from DejaVu Sans (TextPath), 5 handles (Fig. 8, 9)",
    )


def _octopus():
    parts = [ellipse((0, 0.35), 0.32, 0.38)]
    tips = []
    s = np.linspace(0, 1, 12)
    wave = 0.1 * np.array([cos_sin(2 * math.pi * v)[1] for v in s]) * s
    for k in range(8):
        d = np.array(cos_sin(math.pi * (1.0 + k / 7)))  # fan out below the head
        base = np.array([0.2 * d[0], 0.2 + 0.2 * d[1]])
        nrm = np.array([-d[1], d[0]])
        curve = base + (s * 0.8)[:, None] * d[None] + wave[:, None] * nrm[None]
        parts.append(chain(curve, 0.075, 0.03))
        tips.append(curve[-1] - 0.03 * d)
    handles = np.vstack(tips + [np.array([[0, 0.5]])])
    mix = Mixture((Disc(0.18), Voronoi(0.45)), (0.5, 0.5))
    return _from_field(
        union(*parts),
        [[-1.2, -1.0], [1.2, 0.85]],
        "octopus",
        handles,
        [True] * 9,
        [mix] * 8 + [Disc(0.12)],
        "octopus: 8 tentacle tips and the head; samples from discs and Voronoi cells (Fig. 1)",
    )


def _crab():
    parts = [ellipse((0, 0), 0.42, 0.28)]
    handles = []
    for sgn in (-1, 1):
        # claws: arm + two pincer fingers
        arm = np.array([[0.25 * sgn, 0.15], [0.45 * sgn, 0.4], [0.5 * sgn, 0.62]])
        parts.append(chain(arm, 0.07, 0.06))
        parts.append(ellipse((0.52 * sgn, 0.72), 0.11, 0.14))
        parts.append(capsule((0.46 * sgn, 0.78), (0.38 * sgn, 0.97), 0.05, 0.025))
        parts.append(capsule((0.6 * sgn, 0.78), (0.62 * sgn, 0.97), 0.05, 0.025))
        handles.append([0.52 * sgn, 0.72])
        # four legs per side
        for k in range(4):
            y0 = 0.08 - 0.12 * k
            knee = np.array([(0.62 - 0.03 * k) * sgn, y0 + 0.06])
            foot = np.array([(0.8 + 0.02 * k) * sgn, y0 - 0.3 - 0.08 * k])
            parts.append(chain(np.array([[0.15 * sgn, 0.6 * y0], knee, foot]), 0.042, 0.022))
            leg = foot - knee
            handles.append(foot - 0.03 * leg / math.sqrt(leg[0] * leg[0] + leg[1] * leg[1]))
        parts.append(capsule((0.12 * sgn, 0.2), (0.14 * sgn, 0.36), 0.03, 0.035))  # eye stalks
    # 2 claws + 8 legs = 10 moving, 1 fixed at the body centre
    return _from_field(
        union(*parts),
        [[-1.05, -1.0], [1.05, 1.05]],
        "crab",
        np.vstack([handles, [[0.0, 0.0]]]),
        [True] * 10 + [False],
        [Disc(0.15)] * 10,
        "crab: claws and 8 legs move, the body centre is held (Fig. 2)",
    )


def _dino():
    body = ellipse((0, 0), 0.45, 0.25)
    neck = chain(np.array([[0.3, 0.1], [0.55, 0.45], [0.7, 0.75]]), 0.13, 0.08)
    head = ellipse((0.8, 0.8), 0.14, 0.08, angle=-0.2)
    tail = chain(np.array([[-0.35, 0.0], [-0.75, 0.1], [-1.05, 0.3], [-1.3, 0.35]]), 0.16, 0.03)
    legs = [capsule((x, -0.1), (x + 0.03, -0.55), 0.09, 0.07) for x in (-0.25, -0.1, 0.12, 0.27)]
    return _from_field(
        union(body, neck, head, tail, *legs),
        [[-1.45, -0.7], [1.05, 1.0]],
        "dino",
        [[0.85, 0.8], [-1.27, 0.35], [-0.22, -0.52], [0.3, -0.52]],
        [True, True, False, False],
        [Disc(0.3)] * 2,
        "dinosaur: head and tail tip move, the feet stand (Table 1)",
    )


@dataclasses.dataclass
class Solid:
    """Geometry of a named 3D shape, before tetrahedral meshing.

    Attributes
    ----------
    name : str
    inside : callable
        ``inside(P (k,3)) -> (k,) bool``.
    bbox : (2,3) numpy array
    handles : (h,3) numpy array
        Handle points; each becomes its nearest mesh vertex (they lie inside the solid).
    moving : (h,) bool numpy array
    regions : list of dict
        One per moving handle, ``{"kind": "ball", "radius": r}``.
    description : str
    project : callable, optional
        ``project(P (k,3)) -> (k,3)``, the nearest surface point (snaps the mesh boundary).
    spacing : callable, optional
        ``spacing(n_vertices) -> h``; by default h is fitted to the vertex count.
    surface : tuple of (V (k,3), F (l,3)), optional
        A finer closed surface to embed in the mesh (for drawing).
    """

    name: str
    inside: Callable
    bbox: np.ndarray
    handles: np.ndarray
    moving: np.ndarray
    regions: list
    description: str
    project: Callable | None = None
    spacing: Callable | None = None
    surface: tuple | None = None

    def mesh(self, n_vertices):
        """The tetrahedral mesh with about ``n_vertices`` vertices (:func:`defop.geometry.volumetric.tet_mesh`)."""
        h = self.spacing(n_vertices) if self.spacing else mesher.grid_spacing(self.inside, self.bbox, n_vertices)
        return mesher.tet_mesh(self.inside, self.bbox, h, project=self.project)


def _ball(r):
    return {"kind": "ball", "radius": r}


def _beam(name, size, moving, description):
    """A box [0, size]: a patch of 4 fixed handles on its left end face, the ``moving`` (y, z) fractions on its
    right end face."""
    size = np.asarray(size, float)
    thin = float(size[1:].min())

    def inside(P):
        return (P > 0).all(axis=1) & (P < size).all(axis=1)

    # a handle at half the width must sit on a grid plane (midway between two it would snap to one side): even k
    even = any(0.5 in f for f in moving)

    def spacing(n):  # an integer number of cubes across the thin side: the faces of the beam lie on the grid
        cubes = np.round(size / thin).astype(int)
        k = min(range(2, 60, 2 if even else 1), key=lambda k: abs(int(np.prod(cubes * k + 1)) - n))
        return thin / k

    ring = [(0.2, 0.2), (0.8, 0.2), (0.8, 0.8), (0.2, 0.8)]  # fractions of the end face, never midway

    def at(x, y, z):  # rounded: 0.2 · 0.2 is 0.04000000000000001 in floating point
        return [x, round(y * float(size[1]), 12), round(z * float(size[2]), 12)]

    handles = [at(0.0, y, z) for y, z in ring] + [at(float(size[0]), y, z) for y, z in moving]
    return Solid(
        name,
        inside,
        np.array([[0, 0, 0], size]),
        np.array(handles),
        np.array([False] * 4 + [True] * len(moving)),
        [_ball(0.12)] * len(moving),
        description,
        spacing=spacing,
    )


def _bar_3d():
    return _beam(
        "bar_3d",
        (1.0, 0.2, 0.2),
        [(0.2, 0.2), (0.8, 0.2), (0.8, 0.8), (0.2, 0.8)],
        "1 x 0.2 x 0.2 beam: a patch of 4 fixed handles clamps the left end face, 4 moving handles on the right "
        "end face twist or bend it (Fig. 7 in 3D)",
    )


def _plank_3d():
    return _beam(
        "plank_3d",
        (1.0, 0.2, 0.4),
        [(0.5, 0.5)],
        "1 x 0.2 x 0.4 plank (Fig. 10's bar in 3D), clamped by 4 fixed handles on the left end face; one moving "
        "handle at the centre of the right end face lets that end turn like the bar's one handle: pushed in along "
        "its axis it buckles up or down in y, its thin direction",
    )


def _octopus_3d():
    parts = [ellipsoid((0, 0, 0.45), (0.34, 0.34, 0.42))]
    tips = []
    s = np.linspace(0, 1, 10)
    for k in range(8):
        c, si = cos_sin(2 * math.pi * (k + 0.5) / 8)
        wave = np.array([cos_sin(2 * math.pi * v)[1] for v in s])
        rad = 0.15 + 0.85 * s
        curve = np.column_stack(
            [rad * c - 0.1 * wave * s * si, rad * si + 0.1 * wave * s * c, 0.25 - 0.35 * s + 0.2 * s * s]
        )
        parts.append(chain(curve, 0.12, 0.055))
        tips.append(curve[-1] - [0.05 * c, 0.05 * si, 0.0])
    field = union(*parts)
    bbox = np.array([[-1.15, -1.15, -0.2], [1.15, 1.15, 0.9]])
    return Solid(
        "octopus_3d",
        lambda P: field(P) > 0,
        bbox,
        np.vstack(tips + [np.array([[0.0, 0.0, 0.5]])]),
        np.ones(9, bool),
        [_ball(0.25)] * 8 + [_ball(0.12)],
        "octopus: a head ellipsoid and 8 tapered, waving arms (an implicit union); handles at the 8 arm tips and "
        "the head (Fig. 1 in 3D)",
        project=mesher.field_projector(field, 0.01),
    )


def pyvista_example_path(filename):
    """The path of a data file shipped in the installed PyVista wheel's examples (PyVista is not imported)."""
    spec = importlib.util.find_spec("pyvista")
    if spec is None or not spec.submodule_search_locations:
        raise ValueError(f"{filename} comes with PyVista's wheel, and PyVista is not installed")
    path = Path(list(spec.submodule_search_locations)[0]) / "examples" / filename
    if not path.exists():
        raise ValueError(f"{path} is missing from the installed PyVista (0.49 ships it)")
    return path


def _nut():
    V, F = surfaces.check_surface(*surfaces.read_surface(pyvista_example_path("nut.ply")))
    lo, hi = V.min(axis=0), V.max(axis=0)
    scale = 1.0 / float(np.ptp(V, axis=0).max())
    V = (V - lo) * scale  # about 1 x 0.63 x 1, the axis of the hole along y
    c = (hi - lo) * scale / 2
    handles = [[c[0], c[1], 0.04], [c[0], c[1], 0.96], [0.04, c[1], c[2]], [0.96, c[1], c[2]]]
    return Solid(
        "nut",
        surfaces.inside_surface(V, F),
        np.array([V.min(axis=0), V.max(axis=0)]),
        np.array(handles),
        np.array([True, True, False, True]),
        [_ball(0.15)] * 3,
        "a hexagonal nut (PyVista's example nut.ply, a closed genus-1 surface of 523 vertices) meshed by Kuhn "
        "cubes; three outer faces move, one is held",
        project=surfaces.surface_projector(V, F),
        surface=(V, F),
    )


CATALOGUE = {
    "bar": _bar,
    "u_shape": _u_shape,
    "gingerbread": _gingerbread,
    "aleph": _aleph,
    "octopus": _octopus,
    "crab": _crab,
    "dino": _dino,
}

SOLIDS = {
    "bar_3d": _bar_3d,
    "plank_3d": _plank_3d,
    "octopus_3d": _octopus_3d,
    "nut": _nut,
}

_DEFAULT_VERTICES = {
    "bar_3d": 1500,
    "plank_3d": 1000,
    "octopus_3d": 10000,
    "nut": 3000,
    "bar": 600,
    "u_shape": 800,
    "gingerbread": 1200,
    "aleph": 2900,
    "octopus": 4000,
    "crab": 2100,
    "dino": 1700,
}


def check_name(name):
    """Raise ValueError listing the known names if ``name`` is not one."""
    if not isinstance(name, str) or (name not in CATALOGUE and name not in SOLIDS):
        raise ValueError(f"unknown shape {name!r}; known shapes: {', '.join([*CATALOGUE, *SOLIDS])}")


def dim(name):
    """2 for the planar models, 3 for the solids."""
    check_name(name)
    return 3 if name in SOLIDS else 2


def model(name):
    """The geometry of a named model.

    Parameters
    ----------
    name : str

    Returns
    -------
    model : Model or Solid
        A :class:`Model` (planar outline) or a :class:`Solid` (3D).
    """
    check_name(name)
    return SOLIDS[name]() if name in SOLIDS else CATALOGUE[name]()


def default_vertices(name):
    """The default vertex count of a named shape (near Table 1)."""
    check_name(name)
    return _DEFAULT_VERTICES[name]

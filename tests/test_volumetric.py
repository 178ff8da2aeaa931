"""Volumetric meshing: Kuhn cubes, cleaning into a manifold solid, snapping, closed surfaces, 3D shapes.

Analytic checks (volumes of boxes and balls), property checks on random cube sets (every one gives a valid
tetrahedral mesh with a closed manifold boundary), the rejections of bad surfaces and handles, the
catalogue's solids and their sizes. Reproducibility across BLAS kernels is in test_reproducible_meshes.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import ndimage

import defop as dop
from defop.geometry.fields import capsule, ellipsoid, union
from defop.geometry.mesh import Mesh
from defop.geometry.volumetric import grid, mesher
from defop.geometry.volumetric import surface as surf
from defop.scene import models
from defop.scene.regions import REGION_KINDS

needs_ball = pytest.mark.skipif("ball" not in REGION_KINDS, reason="ball regions come with the operator branch")


def box_surface(lo=(0, 0, 0), n=(2, 1, 1), h=0.5):
    """The closed, outward-oriented boundary of a box of Kuhn cubes: (V, F)."""
    V, T = grid.cubes_to_tets(np.ones(n, bool), np.asarray(lo, float), h)
    S = Mesh(V, T).boundary_facets
    used, F = np.unique(S, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def glued(A, B):
    """Two surfaces as one, with coinciding vertices merged."""
    V = np.vstack([A[0], B[0]])
    F = np.vstack([A[1], B[1] + len(A[0])])
    V, inv = np.unique(V, axis=0, return_inverse=True)
    return V, inv.ravel()[F]


# ------------------------------------------------------------------------------------------------ cubes
@settings(max_examples=40, deadline=None)
@given(arrays(bool, (5, 4, 4)))
def test_any_cube_set_cleans_into_a_valid_tet_mesh(occ):
    occ = np.pad(occ, 3)
    if not occ.any():
        return
    clean = grid.clean_cubes(occ)
    label, _ = ndimage.label(occ)
    largest = label == 1 + int(np.argmax(np.bincount(label.ravel())[1:]))
    assert (clean | ~largest).all()  # keeps the largest piece, adds cubes, drops smaller pieces
    V, T = grid.cubes_to_tets(clean, np.zeros(3), 1.0)
    m = Mesh(V, T)  # validates: positive volumes, face-to-face, closed manifold boundary, no unused vertex
    assert m.volumes.sum() == pytest.approx(clean.sum())
    assert np.allclose(m.volumes, 1 / 6)


def test_cleaning_joins_cubes_meeting_at_an_edge_and_fills_a_cavity():
    occ = np.zeros((6, 6, 6), bool)
    occ[2, 2, 2] = occ[3, 3, 2] = True  # meet along an edge only
    clean = grid.clean_cubes(occ)
    assert clean[2:4, 2:4, 2].all() and clean.sum() <= 16  # the 2x2x2 blocks at the edge's ends
    shell = np.zeros((7, 7, 7), bool)
    shell[2:5, 2:5, 2:5] = True
    shell[3, 3, 3] = False  # a cavity
    assert grid.clean_cubes(shell)[3, 3, 3]


def test_kuhn_tets_of_neighbouring_cubes_share_faces():
    V, T = grid.cubes_to_tets(np.ones((3, 3, 3), bool), np.zeros(3), 1 / 3)
    m = Mesh(V, T)
    assert m.n_faces == 6 * 27 and m.volumes.sum() == pytest.approx(1.0)
    assert len(m.boundary_facets) == 6 * 9 * 2  # only the outer squares are boundary


# ----------------------------------------------------------------------------------------- fields, snapping
def test_ball_mesh_volume_thickness_and_snapping():
    r, h = 0.5, 0.08
    f = ellipsoid((0, 0, 0), (r, r, r))
    m = mesher.tet_mesh(lambda P: f(P) > 0, [[-r, -r, -r], [r, r, r]], h, project=mesher.field_projector(f, h))
    assert m.volumes.sum() == pytest.approx(4 / 3 * math.pi * r**3, rel=0.03)
    assert m.volumes.min() >= 0.1 * h**3 / 6 * (1 - 1e-12)
    d = np.abs(f(m.V[m.boundary_vertices]))
    assert np.median(d) < 0.05 * h and np.percentile(d, 90) < 0.15 * h and d.max() < 0.5 * h
    voxel = mesher.tet_mesh(lambda P: f(P) > 0, [[-r, -r, -r], [r, r, r]], h)
    assert np.median(np.abs(f(voxel.V[voxel.boundary_vertices]))) > np.median(d)


@settings(max_examples=8, deadline=None)
@given(st.tuples(*[st.floats(0.2, 0.6)] * 3), st.floats(-0.3, 0.3))
def test_random_ellipsoids_mesh_to_their_volume(radii, shift):
    h = min(radii) / 4
    f = ellipsoid((shift, 0.0, -shift), radii)
    lo, hi = np.array([shift, 0, -shift]) - radii, np.array([shift, 0, -shift]) + radii
    m = mesher.tet_mesh(lambda P: f(P) > 0, [lo, hi], h, project=mesher.field_projector(f, h))
    assert m.volumes.sum() == pytest.approx(4 / 3 * math.pi * np.prod(radii), rel=0.06)
    assert m.volumes.min() >= 0.1 * h**3 / 6 * (1 - 1e-12)


@settings(max_examples=5, deadline=None)
@given(st.integers(800, 4000))
def test_grid_spacing_gives_about_the_asked_vertex_count(n):
    f = union(ellipsoid((0, 0, 0), (0.5, 0.4, 0.3)), capsule((0.3, 0, 0), (1.0, 0.2, 0.1), 0.15, 0.08))
    bbox = [[-0.6, -0.5, -0.4], [1.2, 0.5, 0.4]]
    h = mesher.grid_spacing(lambda P: f(P) > 0, bbox, n)
    m = mesher.tet_mesh(lambda P: f(P) > 0, bbox, h)
    assert abs(m.n_vertices - n) < 0.15 * n


def test_snapping_keeps_every_tet_thick_even_with_wild_targets():
    V, T = grid.cubes_to_tets(np.ones((3, 3, 3), bool), np.zeros(3), 1.0)
    target = V + np.random.default_rng(0).normal(0, 0.8, V.shape)
    X = mesher.snap_boundary(V, T, target, 1.0, min_volume=0.3)
    assert dop.geometry.mesh.signed_volumes(X, T).min() >= 0.3 / 6 - 1e-12
    assert np.abs(X - V).max() > 0.1  # it did move some


@pytest.mark.parametrize(
    "bbox, h, match",
    [
        ([[0, 0], [1, 1]], 0.1, "bbox must be"),
        ([[0, 0, 0], [1, 1, -1]], 0.1, "bbox must be"),
        ([[0, 0, 0], [1, 1, 1]], -0.1, "h must be a positive number"),
        ([[0, 0, 0], [1, 1, 1]], 0.1, "no cube of side 0.1 has its centre inside"),
    ],
)
def test_tet_mesh_rejects_bad_arguments(bbox, h, match):
    with pytest.raises(ValueError, match=match):
        mesher.tet_mesh(lambda P: np.zeros(len(P), bool), bbox, h)


# -------------------------------------------------------------------------------------------- surfaces
def test_box_surface_passes_and_inward_orientation_is_flipped():
    V, F = box_surface()
    V2, F2 = surf.check_surface(V, F)
    assert np.array_equal(F2, F) and surf.enclosed_volume(V, F) == pytest.approx(0.25)
    _, F3 = surf.check_surface(V, F[:, ::-1])
    assert surf.enclosed_volume(V, F3) == pytest.approx(0.25)


def _flip_one(V, F):
    F = F.copy()
    F[0] = F[0, ::-1]
    return V, F


def _push_through(V, F):
    V = V.copy()
    V[np.argmin(V.sum(1))] = [1.3, 0.3, 0.6]  # the corner (0,0,0) pushed out through the face x = 1
    return V, F


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: (box_surface()[0], box_surface()[1][1:]), r"the surface is open: edge \(\d+, \d+\) lies in only 1"),
        (lambda: glued(box_surface(n=(1, 1, 1), h=1), box_surface((1, 1, 0), (1, 1, 1), 1)), "lies in 4 triangles"),
        (lambda: glued(box_surface(n=(1, 1, 1), h=1), box_surface((1, 1, 1), (1, 1, 1), 1)), "not a manifold vertex"),
        (lambda: _flip_one(*box_surface()), "not consistently oriented"),
        (lambda: glued(box_surface(), box_surface((0.3, 0.3, 0.3))), r"intersects itself: triangles \d+ and \d+"),
        (lambda: _push_through(*box_surface(n=(1, 1, 1), h=1.0)), "intersects itself"),
        (lambda: (box_surface()[0][:, :2], box_surface()[1]), r"V must have shape \(n,3\)"),
        (lambda: (box_surface()[0], box_surface()[1] + 100), "F must hold integer vertex indices from 0 to"),
        (lambda: (np.vstack([box_surface()[0], [[9, 9, 9]]]), box_surface()[1]), "surface vertices are in no"),
    ],
)
def test_bad_surfaces_are_rejected(make, match):
    V, F = make()
    with pytest.raises(ValueError, match=match):
        surf.check_surface(V, F)


def test_overlapping_closed_parts_are_a_union_when_asked():
    V, F = glued(box_surface(), box_surface((0.3, 0.3, 0.3)))
    with pytest.raises(ValueError, match="overlapping_parts=True"):
        surf.check_surface(V, F)
    surf.check_surface(V, F, overlapping_parts=True)
    m = surf.surface_mesh(V, F, n_vertices=1500, overlapping_parts=True)
    union_volume = 0.25 + 0.25 - 0.7 * 0.2 * 0.2  # two 1 x .5 x .5 boxes overlapping in .7 x .2 x .2
    assert m.volumes.sum() == pytest.approx(union_volume, rel=0.05)


def test_embedded_surface_follows_an_affine_map():
    V, F = box_surface(n=(2, 1, 1), h=0.5)
    m = surf.surface_mesh(V, F, n_vertices=400)
    emb = surf.EmbeddedSurface.embed(m, V, F)
    assert np.allclose(emb.deform(m.V), V, atol=1e-12)
    A = np.array([[1.1, 0.2, 0], [0, 0.9, 0.3], [0.1, 0, 1.2]])
    assert np.allclose(emb.deform(m.V @ A.T + 1), V @ A.T + 1, atol=1e-12)
    with pytest.raises(ValueError, match=r"X must have shape \(n,3\)"):
        emb.deform(m.V[:, :2])


# ------------------------------------------------------------------------------------------- shapes
NUT_HANDLES = np.array([[23, 14, 2], [23, 14, 44], [2, 14, 23]], float)


@pytest.fixture(scope="module")
def nut_surface():
    return surf.read_surface(models.pyvista_example_path("nut.ply"))


def test_from_surface_meshes_the_nut(nut_surface):
    V, F = nut_surface
    regions = [{"kind": "disc", "radius": 1.0}] * 3  # any valid region: what is checked here is the mesh
    s = dop.shapes.from_surface(V, F, handles=V.min(0) + NUT_HANDLES, regions=regions, n_vertices=1200)
    assert s.mesh.dim == 3 and 1000 < s.mesh.n_vertices < 1400
    assert s.mesh.volumes.sum() == pytest.approx(surf.enclosed_volume(V, F), rel=0.05)
    assert np.allclose(s.surface.deform(s.mesh.V), V, atol=1e-9)
    assert s.targets(s.P_moving).shape == (3, 3)
    with pytest.raises(ValueError, match=r"Q must have shape \(3, 3\)"):
        s.targets(s.P_moving[:, :2])


@pytest.mark.parametrize(
    "handles, match",
    [
        ([[23, 14, 2], [23, 14, 44], [23, 14, 60]], r"handle 2 is outside the mesh \(nearest vertex is 14.\d away\)"),
        ([[23, 14, 2], [23, 14, 44], [23, 14, 23]], r"handle 2 is outside the mesh \(nearest vertex is 13.\d away\)"),
        ([[23, 14, 2], [23, 14, 44], [23, 14, 43.9]], "handles 1 and 2 both become vertex"),
        ([[23, 14, 2], [23, 14, 44], [23, 14, 40]], "the 3 handles lie on one line"),
        ([[23, 14, 2], [23, 14, 44]], "the 2 handles lie on one line"),
        ([[23, 14, 2, 0]], r"handles must have shape \(h,3\)"),
    ],
)
def test_from_surface_rejects_bad_handles(nut_surface, handles, match):
    V, F = nut_surface
    H = np.array(handles, float)
    H[:, :3] += V.min(0)
    regions = [{"kind": "disc", "radius": 1.0}] * len(H)
    with pytest.raises(ValueError, match=match):
        dop.shapes.from_surface(V, F, handles=H, regions=regions, n_vertices=800)


def test_from_surface_rejects_an_open_surface_before_meshing(nut_surface):
    V, F = nut_surface
    with pytest.raises(ValueError, match="the surface is open"):
        dop.shapes.from_surface(V, F[1:], handles=V.min(0) + NUT_HANDLES)
    with pytest.raises(ValueError, match="n_auto_handles must be an integer >= 1"):  # automatic handles: >= 1
        dop.shapes.from_surface(V, F, n_auto_handles=0)
    with pytest.raises(ValueError, match="n_vertices must be an integer >= 100"):
        dop.shapes.from_surface(V, F, handles=V.min(0) + NUT_HANDLES, n_vertices=50)


# ---------------------------------------------------------------------------------------------- catalogue
def test_names_keep_the_planar_catalogue_by_default():
    assert dop.shapes.names() == list(models.CATALOGUE)
    solids = ["bar_3d", "plank_3d", "octopus_3d", "nut"]
    assert dop.shapes.names(dim=3) == solids
    assert dop.shapes.names(dim=None) == list(models.CATALOGUE) + solids
    with pytest.raises(ValueError, match="dim must be 2, 3 or None"):
        dop.shapes.names(dim=4)


@pytest.mark.parametrize("name", ["bar_3d", "plank_3d", "octopus_3d", "nut"])
def test_catalogue_solids_mesh_at_their_default_size(name):
    solid = models.model(name)
    n = models.default_vertices(name)
    m = solid.mesh(n)
    assert m.dim == 3 and abs(m.n_vertices - n) < 0.15 * n
    assert (m.volumes > 0).all() and m.contains(solid.handles).all()
    if name in ("bar_3d", "plank_3d"):  # the beam's faces lie on the grid: exact volume
        assert m.volumes.sum() == pytest.approx(0.2 * (0.2 if name == "bar_3d" else 0.4) * 1.0)


def test_the_planks_moving_handle_sits_on_its_mid_line():  # up and down are mirror images: no side preferred
    for n in (165, 448, None, 1716, 2821):  # 448 and 1716 are nearest odd k, which would put 0.1 midway
        shape = dop.shapes.load("plank_3d", n)
        assert np.abs(shape.mesh.V[shape.handles[shape.moving]] - [1.0, 0.1, 0.2]).max() < 1e-12


def test_catalogue_spans_1k_to_10k_vertices():
    sizes = [models.default_vertices(n) for n in dop.shapes.names(dim=3)]
    assert min(sizes) <= 1500 and max(sizes) >= 10000


@needs_ball
@pytest.mark.parametrize("name", ["bar_3d", "nut"])
def test_load_a_solid(name):
    s = dop.shapes.load(name)
    assert s.mesh.dim == 3 and s.P.shape[1] == 3 and s.n_moving == len(s.regions)
    assert s.regions[0]["kind"] == "ball"

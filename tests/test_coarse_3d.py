"""The coarse level of a tetrahedral mesh: Kuhn cubes at twice the spacing, handles as vertices, the prolongation,
and multilevel training in 3D."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.geometry.coarse import OUTSIDE, CoarseningError, coarse_mesh_of, n_parts, prolongation
from defop.geometry.mesh import Mesh
from defop.geometry.volumetric.coarsening import MIN_VOLUME, coarse_solid_mesh, fine_spacing, insert_points
from defop.geometry.volumetric.grid import cubes_to_tets
from defop.training import multilevel as ml
from defop.variational.solver import Solver


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))


@pytest.fixture(scope="module")
def solids():
    return {name: dop.shapes.load(name, n) for name, n in [("bar_3d", 1500), ("nut", 3000)]}


@pytest.mark.parametrize("name", ["bar_3d", "nut"])
def test_coarse_solid_keeps_the_handles_and_covers_the_fine_mesh(solids, name):
    shape = solids[name]
    lv = ml.coarse_level(shape)
    fine, coarse = shape.mesh, lv.coarse.mesh
    assert coarse.dim == 3 and 0.08 < coarse.n_vertices / fine.n_vertices < 0.5
    assert np.array_equal(coarse.V[lv.coarse.handles], shape.P)  # each handle is a coarse vertex, bit for bit
    assert np.array_equal(lv.coarse.moving, shape.moving)
    assert abs(coarse.volumes.sum() / fine.volumes.sum() - 1) < 0.02  # the same solid
    assert n_parts(coarse.F, coarse.n_vertices) == n_parts(fine.F, fine.n_vertices) == 1
    # every fine vertex is in a coarse tetrahedron or just outside one (where the coarse boundary cuts a corner)
    _, bary = coarse.locate(fine.V)
    assert -bary.min() < OUTSIDE
    # no coarse tetrahedron thinner than the floor (Kuhn cubes of twice the fine spacing)
    assert coarse.volumes.min() >= MIN_VOLUME * (2 * fine_spacing(fine)) ** 3 / 6


@pytest.mark.parametrize("name", ["bar_3d", "nut"])
def test_prolongation_in_3d_rest_handles_and_affine_maps(solids, name):
    shape = solids[name]
    lv = ml.coarse_level(shape)
    Vc, Vf = lv.coarse.mesh.V, shape.mesh.V
    assert np.array_equal(lv.prolongate(Vc), Vf)  # rest pose -> rest pose, bit for bit
    rng = np.random.default_rng(3)
    Xc = Vc + 0.02 * rng.standard_normal(Vc.shape)
    assert np.array_equal(lv.prolongate(Xc)[shape.handles], Xc[lv.coarse.handles])
    A, b = np.eye(3) + 0.3 * rng.standard_normal((3, 3)), rng.standard_normal(3)
    X = lv.prolongate(Vc @ A.T + b)
    assert np.abs(X - (Vf @ A.T + b)).max() < 1e-12


def _cube():
    """One Kuhn cube of side 2: 8 vertices, 6 tetrahedra."""
    return cubes_to_tets(np.ones((1, 1, 1), bool), np.zeros(3), 2.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 2.0), min_size=3, max_size=3), st.integers(0, 2**31 - 1))
def test_inserted_point_is_a_vertex_and_affine_maps_are_reproduced(p, seed):
    """Any point of a cube becomes a vertex (or is refused for a thin tetrahedron); a split keeps the volume, and the
    barycentric coordinates of any points reproduce a random affine map exactly."""
    V, T = _cube()
    p = np.array(p)
    try:
        V2, T2, idx = insert_points(V, T, p[None], floor=1e-3)
    except ValueError as exc:
        assert "cannot become a vertex" in str(exc)
        return
    mesh = Mesh(V2, T2)
    assert np.array_equal(mesh.V[idx[0]], p)
    assert mesh.volumes.min() >= 1e-3
    if len(V2) > len(V) and min(p.min(), (2 - p).min()) > 0.2:  # split away from the cube's faces: the same cube
        assert mesh.volumes.sum() == pytest.approx(8.0, rel=1e-12)
    rng = np.random.default_rng(seed)
    A, b = rng.standard_normal((3, 3)), rng.standard_normal(3)
    pts = 2.0 * rng.random((50, 3))
    P = prolongation(pts, mesh)
    assert np.abs(P @ (mesh.V @ A.T + b) - (pts @ A.T + b)).max() < 1e-12


def test_insert_points_on_an_edge_a_face_and_inside():
    V, T = _cube()
    # the cube's centre is the midpoint of the Kuhn diagonal, an edge of all 6 tetrahedra: each splits in two
    V2, T2, idx = insert_points(V, T, np.array([[1.0, 1.0, 1.0]]), floor=1e-3)
    assert len(T2) == 12 and len(V2) == 9 and idx.tolist() == [8]
    # a corner is already a vertex: nothing is added
    V3, T3, idx = insert_points(V, T, np.array([[2.0, 2.0, 2.0]]), floor=1e-3)
    assert len(V3) == 8 and np.array_equal(T3, T) and idx.tolist() == [7]
    with pytest.raises(ValueError, match="outside"):
        insert_points(V, T, np.array([[5.0, 5.0, 5.0]]), floor=1e-3)


def test_coarse_solid_refusals():
    tiny = dop.shapes.load("bar_3d", n_vertices=300)
    with pytest.raises(CoarseningError, match="saves nothing"):
        coarse_mesh_of(tiny.mesh, [], tiny.P, 8, 150)
    coarse, idx = coarse_solid_mesh(tiny.mesh, tiny.P)
    assert np.array_equal(coarse.V[idx], tiny.P) and coarse.n_vertices < tiny.mesh.n_vertices / 2


def test_multilevel_in_3d_gives_verified_samples(monkeypatch):
    """A tiny solid trained on two levels: every sample a verified fine minimum, none above the full policy's."""
    shape = dop.shapes.load("bar_3d", n_vertices=300)
    monkeypatch.setattr(ml, "MIN_COARSE_VERTICES", 50)
    rng = np.random.default_rng(11)
    P = shape.P_moving
    samples = np.array([P + 0.03 * rng.standard_normal(3) + 0.005 * rng.standard_normal(P.shape) for _ in range(13)])
    runs = {}
    for policy in ("multilevel", "full"):
        runs[policy] = dop.train(
            shape, "sarap", "linear", samples=samples, n_jobs=1, progress=False, policy=policy, cache=False, rounds=1
        )[1]
    rec = runs["multilevel"]
    assert rec.policy == "multilevel" and rec.multilevel["coarse_vertices"] < shape.mesh.n_vertices / 2
    s = Solver(shape.mesh, shape.handles, "sarap")
    assert rec.converged.all()
    assert all(s.verify(X, s.targets_of(shape.targets(q))).ok for q, X in zip(rec.samples, rec.X))
    E = np.array([s.energy_of(X) for X in rec.X])
    E_full = np.array([s.energy_of(X) for X in runs["full"].X])
    assert np.all(E <= E_full * (1 + 1e-6) + 1e-12)

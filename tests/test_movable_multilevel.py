"""The joint (P, Q) samples through the coarse level: the multilevel policy with the placement's handles on both
meshes, the same verified minima as the full-mesh solves, its record and its cache key."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import defop as dop
from defop.geometry.planar.meshing import triangulate
from defop.geometry.planar.polygon import distance_to_outline
from defop.scene.placement import placement_regions
from defop.training import multilevel as ml
from defop.training.movable import joint_level, sample_joint, solve_joint, train_movable
from defop.variational.solver import Solver


@pytest.fixture(scope="module")
def bar():
    shape = dop.shapes.load("bar")
    return shape, placement_regions(shape, radius=0.05 * shape.mesh.bbox_diagonal)


def test_every_placement_is_on_the_coarse_mesh(bar):
    """Each region vertex (those on the outline too) is a coarse vertex at the same rest position, bit for bit."""
    shape, pr = bar
    used, lv, why = joint_level(shape, pr, "multilevel")
    assert used == "multilevel" and why == ""
    on = distance_to_outline(shape.mesh.V[pr.vertices[0]], shape.outline) < 1e-9
    assert on.any() and (~on).any()  # the bar's region reaches its end face
    for v in pr.vertices[0]:
        h = pr.handles_at(np.array([v]))
        at = lv.at(h)
        assert np.array_equal(at.coarse.mesh.V[at.coarse.handles], shape.mesh.V[h])
        assert np.array_equal(at.fine.handles, h)
        Xc = at.coarse.mesh.V.copy()
        Xc[at.coarse.handles] += 0.1  # handles to handles exactly through the prolongation
        assert np.array_equal(at.prolongate(Xc)[h], Xc[at.coarse.handles])
    inner = np.setdiff1d(np.arange(shape.mesh.n_vertices), lv.fine_vertices)[0]
    with pytest.raises(ValueError, match=f"fine vertex {inner} is not a vertex of the coarse mesh"):
        lv.coarse_of([inner])


def test_fixed_handles_keep_their_coarse_level(bar):
    """Without placements the coarse level is the fixed-P training's (the same coarse mesh, bit for bit)."""
    shape, _ = bar
    lv = ml.coarse_level(shape)
    again = ml.coarse_level(shape, vertices=[])
    assert np.array_equal(lv.coarse.mesh.V, again.coarse.mesh.V) and np.array_equal(
        lv.coarse.handles, again.coarse.handles
    )
    assert np.array_equal(lv.fine_vertices, np.sort(shape.handles))


def test_joint_samples_reach_the_full_policys_minima(bar, tmp_path, monkeypatch):
    """Under the multilevel policy each joint sample ends on the verified minimum that the full-mesh solve from
    the rest pose finds (same energy, same map), and the record says which policy ran and what the safeguard did."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    shape, pr = bar
    idx, Q = sample_joint(shape, pr, 6, np.random.default_rng(4))
    Xf, cf = solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, policy="full")
    Xm, cm = solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, policy="multilevel")
    assert cf.all() and cm.all()
    for i, xf, xm in zip(idx, Xf, Xm):
        solver = Solver(shape.mesh, pr.handles_at(i), "sarap")
        ef, em = solver.energy_of(xf), solver.energy_of(xm)
        assert em <= ef * (1 + 1e-8)
        assert np.abs(xm - xf).max() < 1e-5 * shape.mesh.bbox_diagonal
        assert solver.verify(xm, solver.targets_of(xm[pr.handles_at(i)])).ok


def test_train_movable_records_the_policy(bar, tmp_path, monkeypatch):
    """The record says which policy ran, the safeguard's rule per sample and the coarse mesh; in 2D ``auto`` runs
    one level and says why."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    shape, pr = bar
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, rec = train_movable(shape, pr, m=8, seed=2, n_jobs=1, progress=False, policy="multilevel")
        _, auto = train_movable(shape, pr, m=8, seed=2, n_jobs=1, progress=False)
        _, again = train_movable(shape, pr, m=8, seed=2, n_jobs=1, progress=False, policy="multilevel")
    assert rec.policy == "multilevel" and auto.policy == "full" and "2D" in auto.multilevel["fallback"]
    assert len(rec.multilevel["rule"]) == 8 and set(rec.multilevel["rule"]) <= {"", *ml.RULES}
    assert rec.multilevel["coarse_vertices"] < shape.mesh.n_vertices and rec.multilevel["fallback"] == ""
    assert "rule" not in auto.multilevel
    assert np.array_equal(again.X, rec.X) and again.multilevel == rec.multilevel  # the cached truth, its record
    with pytest.raises(ValueError, match="policy"):
        train_movable(shape, pr, m=8, n_jobs=1, progress=False, policy="coarse")


def test_the_policy_is_part_of_the_cache_key(bar, tmp_path, monkeypatch):
    """A truth solved under one policy is never read as the other's."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    shape, pr = bar
    idx, Q = sample_joint(shape, pr, 2, np.random.default_rng(5))

    def entries():
        return len(list(tmp_path.rglob("*.npz")))

    solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, policy="full")
    n = entries()
    solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, policy="multilevel")
    assert entries() == n + 1
    solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, policy="auto")  # auto runs full in 2D: a hit
    assert entries() == n + 1


def test_a_shape_without_a_coarse_level_runs_full_and_says_why():
    """Multilevel asked for, no coarse mesh (too few vertices): one level, the reason returned (and warned)."""
    shape = dop.shapes.from_polygon(
        np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]),
        handles=np.array([[1.8, 0.5], [0.1, 0.5]]),
        moving=[True, False],
        n_vertices=200,
        regions=[{"kind": "disc", "radius": 0.1}],
    )
    with pytest.warns(ml.MultilevelWarning, match="runs on one level"):
        used, lv, why = joint_level(shape, placement_regions(shape, [0], radius=0.15), "multilevel")
    assert used == "full" and lv is None and "saves nothing" in why


@hsettings(max_examples=15, deadline=None)
@given(st.lists(st.floats(0.02, 0.98), min_size=1, max_size=6, unique=True), st.integers(0, 3))
def test_points_on_the_outline_become_mesh_vertices(ts, side):
    """triangulate(boundary_points=...): points on an edge of the outline are vertices of the mesh, exactly."""
    outer = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    a, b = outer[side], outer[(side + 1) % 4]
    pts = np.array([a + t * (b - a) for t in ts])
    mesh = triangulate(outer, points=[[1.0, 0.5]], n_vertices=80, boundary_points=pts)
    _, dist = mesh.nearest_vertex(pts)
    assert np.all(dist == 0)


def test_boundary_points_off_the_outline_are_refused():
    outer = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    with pytest.raises(ValueError, match=r"boundary_points\[0\] is 0.1 from the outline"):
        triangulate(outer, n_vertices=80, boundary_points=[[1.0, 0.1]])


def test_a_3d_patch_is_placed_on_the_coarse_mesh():
    """bar_3d's end-face patch: at every region vertex each member is a coarse vertex at the same rest position."""
    shape = dop.shapes.load("bar_3d", 936)
    pr = placement_regions(shape, radius=0.08 * shape.mesh.bbox_diagonal)
    used, lv, _ = joint_level(shape, pr, "auto")  # the default in 3D: two levels
    assert used == "multilevel" and lv.coarse.mesh.n_vertices < shape.mesh.n_vertices / 2
    assert len(pr.members[0]) > 1
    for v in pr.vertices[0]:
        h = pr.handles_at(np.array([v]))
        at = lv.at(h)
        assert np.array_equal(at.coarse.mesh.V[at.coarse.handles], shape.mesh.V[h])

"""Mesh: orientation, areas, Jacobians, mass/cotan matrices, lookup and I/O on tiny analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.geometry.mesh import Mesh


def test_single_triangle_area_and_orientation(triangle):
    assert triangle.areas == pytest.approx([1.0])
    # a clockwise input is re-oriented counter-clockwise
    cw = Mesh(triangle.V, triangle.F[:, ::-1])
    assert dop.geometry.mesh.signed_areas(cw.V, cw.F) == pytest.approx([1.0])


def test_grid_areas_add_up(grid):
    assert grid.areas.sum() == pytest.approx(2.0)
    assert np.all(dop.geometry.mesh.signed_areas(grid.V, grid.F) > 0)


def test_boundary_loop_follows_rectangle(grid):
    loops = grid.boundary_loops()
    assert len(loops) == 1
    b = grid.V[loops[0]]
    on_edge = np.isclose(b[:, 0], 0) | np.isclose(b[:, 0], 2) | np.isclose(b[:, 1], 0) | np.isclose(b[:, 1], 1)
    assert on_edge.all() and len(loops[0]) == 2 * (8 + 4)
    # the loop is a closed walk along the boundary: consecutive vertices are one grid step apart
    steps = np.linalg.norm(np.diff(np.vstack([b, b[:1]]), axis=0), axis=1)
    assert steps.max() == pytest.approx(0.25)


def test_jacobian_of_affine_map_is_its_matrix(grid):
    A = np.array([[1.3, -0.4], [0.2, 0.7]])
    X = grid.V @ A.T + [0.5, -2.0]
    J = grid.jacobians(X)
    assert np.allclose(J, A, atol=1e-12)
    assert np.allclose(grid.jacobians(grid.V), np.eye(2), atol=1e-12)
    G = grid.jacobian_operator
    assert G.shape == (4 * grid.n_faces, 2 * grid.n_vertices)
    assert np.allclose(G @ X.ravel(), J.reshape(-1))


def test_flipped_detects_reflection(grid):
    X = grid.V * [-1.0, 1.0]
    assert grid.flipped(X).all()
    assert not grid.flipped(grid.V).any()


def test_mass_matrix_single_triangle(triangle):
    M = triangle.mass_matrix.toarray()
    assert np.trace(M) == pytest.approx(1.0)  # lumped: sums to the area
    Mf = triangle.mass_matrix_full.toarray()
    # consistent P1 mass matrix: A/12 * [[2,1,1],[1,2,1],[1,1,2]]
    assert np.allclose(Mf, (np.ones((3, 3)) + np.eye(3)) / 12)


def test_cotmatrix_kills_linear_functions(grid):
    L = grid.cotmatrix
    interior = np.setdiff1d(np.arange(grid.n_vertices), grid.boundary_loops()[0])
    for f in (np.ones(grid.n_vertices), grid.V[:, 0], grid.V[:, 1]):
        assert np.allclose((L @ f)[interior], 0, atol=1e-12)
    assert np.allclose(L @ np.ones(grid.n_vertices), 0, atol=1e-12)


def test_nearest_vertex_and_contains(grid):
    idx, dist = grid.nearest_vertex(np.array([[0.01, 0.02], [2.3, 1.0]]))
    assert idx[0] == 0 and dist[0] == pytest.approx(np.hypot(0.01, 0.02))
    assert grid.V[idx[1]] == pytest.approx([2.0, 1.0]) and dist[1] == pytest.approx(0.3)
    assert grid.contains(np.array([[1.0, 0.5], [2.5, 0.5]])).tolist() == [True, False]


@pytest.mark.parametrize("ext", [".npz", ".obj", ".off"])
def test_write_read_round_trip(grid, tmp_path, ext):
    path = tmp_path / f"m{ext}"
    grid.save(path)
    back = Mesh.load(path)
    assert back == grid
    assert np.array_equal(back.F, grid.F) and np.allclose(back.V, grid.V, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    "V, F, match",
    [
        (np.array([[0, 0], [1, np.nan], [0, 1.0]]), np.array([[0, 1, 2]]), "NaN"),
        (np.array([[0, 0], [1, 0], [0, 1.0]]), np.array([[0, 1, 3]]), "triangle 0 indexes vertex 3, but V has 3"),
        (np.array([[0, 0], [1, 0], [0, 1.0]]), np.array([[0, 1, -1]]), "triangle 0 indexes vertex -1, but V has 3"),
        (np.array([[0, 0], [1, 0], [0, 1.0]]), np.array([[0, 1, 2.5]]), "integer vertex indices: triangle 0 has 2.5"),
        (np.array([[0, 0], [1, 0], [0, 1.0]]), np.array([[0, 1, 2]], dtype=complex), "dtype complex"),
        (np.array([[0, 0], [1, 0], [2, 0.0]]), np.array([[0, 1, 2]]), "degenerate"),
        (np.zeros((3, 3)), np.array([[0, 1, 2]]), r"shape \(n,2\)"),
    ],
)
def test_bad_mesh_input(V, F, match):
    with pytest.raises(ValueError, match=match):
        Mesh(V, F)


def test_unknown_format(tmp_path, grid):
    with pytest.raises(ValueError, match="unknown mesh format"):
        grid.save(tmp_path / "m.stl")


SQUARE_V = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])


def test_folded_triangle_is_rejected_not_reoriented():
    """Before: a folded triangle was silently flipped (area 1.5 instead of 1.0)."""
    V = np.vstack([SQUARE_V, [[0.5, 1.5]]])
    F = np.array([[0, 1, 2], [0, 2, 3], [2, 3, 4]])  # the third is clockwise: folded over the second
    with pytest.raises(ValueError, match=r"triangle 2 is inverted \(clockwise, signed area -0.25\)"):
        Mesh(V, F)


def test_all_clockwise_mesh_is_reoriented_consistently(grid):
    cw = Mesh(grid.V, grid.F[:, ::-1])
    assert np.all(dop.geometry.mesh.signed_areas(cw.V, cw.F) > 0) and cw.areas.sum() == pytest.approx(2.0)


def test_non_manifold_edge_is_named():
    """Before: accepted, and boundary_loops returned a one-vertex loop."""
    V = np.array([[0, 0], [1, 0], [0.5, 1], [0.5, -1], [1.5, 0.5]])
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(ValueError, match=r"edge \(0, 1\) is shared by 3 triangles \(0, 1, 2\)"):
        Mesh(V, F)


def test_edge_used_twice_in_one_direction_is_a_fold():
    V = np.array([[0, 0], [1, 0], [0.5, 1], [0.5, 0.5]])
    F = np.array([[0, 1, 2], [0, 1, 3]])  # both counter-clockwise, both on the same side of edge (0, 1)
    with pytest.raises(ValueError, match=r"edge \(0, 1\) is used in the same direction by triangles 0, 1"):
        Mesh(V, F)


def test_unreferenced_vertex_is_named():
    """Before: accepted, and a later solve failed with "matmul: dimension mismatch"."""
    V = np.vstack([SQUARE_V, [[5.0, 5.0]], [[6.0, 5.0]]])
    with pytest.raises(ValueError, match="2 vertices are not used by any triangle, first is vertex 4"):
        Mesh(V, np.array([[0, 1, 2], [0, 2, 3]]))


@pytest.mark.parametrize("name", ["m.NPZ", "m.Npz", "m.npz", "m.OBJ", "m.OFF"])
def test_extension_is_case_insensitive(grid, tmp_path, name):
    """Before: save('m.NPZ') wrote m.NPZ.npz, which read_mesh('m.NPZ') could not find."""
    grid.save(tmp_path / name)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    assert dop.geometry.mesh.read_mesh(tmp_path / name) == grid


def test_bowtie_vertex_is_named():
    """Two triangles touching at one vertex: the boundary is not a set of simple loops."""
    V = np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1.0]])
    with pytest.raises(ValueError, match="vertex 0 is not a manifold vertex: 4 boundary edges meet there"):
        Mesh(V, np.array([[0, 1, 2], [0, 3, 4]]))

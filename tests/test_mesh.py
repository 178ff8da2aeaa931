"""Mesh: orientation, areas, Jacobians, mass/cotan matrices, lookup and I/O on tiny analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import defop as dop
from defop.geometry.mesh import Mesh
from defop.geometry.volumetric import grid as tet_grid


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


# ------------------------------------------------------------------------------------------ 3D: tetrahedra
UNIT_TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
CUBE_V = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], float)


def block(nx=3, ny=2, nz=2, h=0.5):
    """A box of nx × ny × nz Kuhn cubes of side h."""
    V, T = tet_grid.cubes_to_tets(np.ones((nx, ny, nz), bool), np.zeros(3), h)
    return Mesh(V, T)


def test_unit_tet_volume_and_orientation():
    m = Mesh(UNIT_TET, [[0, 1, 2, 3]])
    assert m.dim == 3 and m.volumes == pytest.approx([1 / 6]) and m.areas is m.volumes
    neg = Mesh(UNIT_TET, [[0, 2, 1, 3]])  # negatively oriented: re-oriented
    assert neg.volumes == pytest.approx([1 / 6])
    assert dop.geometry.mesh.signed_volumes(UNIT_TET, np.array([[0, 2, 1, 3]])) == pytest.approx([-1 / 6])
    assert repr(m) == "Mesh(n_vertices=4, n_tets=1, dim=3)"


def test_kuhn_cube_six_tets_fill_the_cube():
    T = tet_grid.kuhn_tets()
    m = Mesh(CUBE_V, T)
    assert m.n_faces == 6 and np.allclose(m.volumes, 1 / 6) and m.volumes.sum() == pytest.approx(1.0)
    assert m.boundary_facets.shape == (12, 3)  # two triangles per square face
    # outward: the boundary triangles' normals point away from the cube centre
    P = m.V[m.boundary_facets]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    assert (np.einsum("ij,ij->i", n, P.mean(1) - 0.5) > 0).all()


def test_block_volume_boundary_and_bbox():
    m = block()
    assert m.volumes.sum() == pytest.approx(1.5 * 1.0 * 1.0) and (m.volumes > 0).all()
    assert m.bbox_diagonal == pytest.approx(np.sqrt(1.5**2 + 1 + 1))
    assert len(m.boundary_vertices) == 4 * 3 * 3 - 2 * 1 * 1  # (4*3*3 vertices, 2 inside)
    dop.geometry.mesh.check_closed_surface(m.boundary_facets)


@given(
    st.lists(st.floats(-2, 2), min_size=9, max_size=9),
    st.lists(st.floats(-5, 5), min_size=3, max_size=3),
)
def test_jacobians_of_an_affine_map_equal_its_matrix(a, t):
    m = block()
    A = np.array(a).reshape(3, 3)
    X = m.V @ A.T + t
    J = m.jacobians(X)
    assert J.shape == (m.n_faces, 3, 3)
    assert np.allclose(J, A, atol=1e-11)
    assert m.jacobian_operator.shape == (9 * m.n_faces, 3 * m.n_vertices)


def test_flipped_tets_under_a_reflection():
    m = block()
    assert m.flipped(m.V * [-1.0, 1.0, 1.0]).all() and not m.flipped(m.V).any()


def test_mass_matrices_sum_to_the_volume():
    m = block()
    assert m.mass_matrix.sum() == pytest.approx(1.5) and (m.mass_matrix.diagonal() > 0).all()
    assert m.mass_matrix_full.sum() == pytest.approx(1.5)
    one = Mesh(UNIT_TET, [[0, 1, 2, 3]])
    assert np.allclose(one.mass_matrix_full.toarray(), (np.ones((4, 4)) + np.eye(4)) / 6 / 20)


def test_cot_laplacian_annihilates_linear_functions_inside():
    m = block(4, 3, 3, 0.25)
    L = m.cotmatrix
    interior = np.setdiff1d(np.arange(m.n_vertices), m.boundary_vertices)
    assert len(interior) == 3 * 2 * 2
    for f in (m.V[:, 0], m.V[:, 1], 2 * m.V[:, 2] - m.V[:, 0]):
        assert np.allclose((L @ f)[interior], 0, atol=1e-12)
    assert np.allclose(L @ np.ones(m.n_vertices), 0, atol=1e-12)


def test_nearest_contains_and_locate_in_3d():
    m = block()
    P = np.array([[0.3, 0.2, 0.6], [1.4, 0.9, 0.1], [2.0, 0.5, 0.5]])
    assert m.contains(P).tolist() == [True, True, False]
    el, bary = m.locate(P[:2])
    assert np.allclose(bary.sum(1), 1) and (bary >= -1e-12).all()
    assert np.allclose((bary[:, :, None] * m.V[m.F[el]]).sum(1), P[:2])
    idx, dist = m.nearest_vertex([[1.6, 1.0, 1.0]])
    assert m.V[idx[0]] == pytest.approx([1.5, 1.0, 1.0]) and dist[0] == pytest.approx(0.1)
    with pytest.raises(ValueError, match=r"points must have shape \(n,3\)"):
        m.nearest_vertex([[0.0, 0.0]])
    with pytest.raises(ValueError, match="boundary_loops is for 2D meshes"):
        m.boundary_loops()


def _two_cubes(offset):
    """Two Kuhn cubes, the second shifted by ``offset`` (sharing a face, an edge or a corner)."""
    V = np.vstack([CUBE_V, CUBE_V + offset])
    T = np.vstack([tet_grid.kuhn_tets(), tet_grid.kuhn_tets() + 8])
    V, inv = np.unique(V, axis=0, return_inverse=True)
    return V, inv.ravel()[T]


def test_two_cubes_sharing_a_face_are_a_mesh():
    m = Mesh(*_two_cubes([1.0, 0, 0]))
    assert m.n_vertices == 12 and m.volumes.sum() == pytest.approx(2.0)


@pytest.mark.parametrize(
    "V, T, match",
    [
        (UNIT_TET, [[0, 1, 2, 3], [0, 1, 2, 3]], "tetrahedra 0 and 1 lie on the same side of their common triangle"),
        (np.vstack([UNIT_TET, [[1, 1, 1.0]]]), [[0, 1, 2, 3], [4, 2, 1, 3]], None),
        (np.vstack([UNIT_TET, [[0.2, 0.2, 0.2]]]), [[0, 1, 2, 3], [4, 1, 2, 3]], r"same side of their common tri"),
        (np.vstack([UNIT_TET, [[1, 1, 1.0]]]), [[0, 1, 2, 3], [4, 1, 2, 3]], r"tetrahedron 1 is inverted"),
        (np.vstack([UNIT_TET, [[0.5, 0.5, 0.0]]]), [[0, 1, 2, 3], [1, 4, 2, 3]], r"degenerate \(zero-volume\)"),
        (np.vstack([UNIT_TET, [[5, 5, 5.0]]]), [[0, 1, 2, 3]], "1 vertices are not used by any tetrahedron, first is "),
        (UNIT_TET, [[0, 1, 2]], r"V must have shape \(n,2\) for triangles F \(m,3\); a 3D mesh is made of tetrahedra"),
        (UNIT_TET[:, :2], [[0, 1, 2, 3]], r"V must have shape \(n,3\) for F of 4 columns \(tetrahedra\)"),
        (UNIT_TET, [[0, 1, 2, 4]], "tetrahedron 0 indexes vertex 4, but V has 4"),
    ],
)
def test_bad_tet_meshes(V, T, match):
    if match is None:  # valid: two tets sharing a face, from opposite sides
        assert Mesh(V, T).n_faces == 2
        return
    with pytest.raises(ValueError, match=match):
        Mesh(V, T)


def test_inverted_tet_is_named_with_its_volume():
    V = np.vstack([UNIT_TET, [[1, 1, 1.0]]])
    with pytest.raises(ValueError, match=r"tetrahedron 1 is inverted \(signed volume -0.333\)"):
        Mesh(V, [[0, 1, 2, 3], [4, 1, 2, 3]])  # the second tet is the mirror of a valid one


def test_cubes_meeting_at_an_edge_or_a_corner_have_no_manifold_boundary():
    with pytest.raises(ValueError, match=r"boundary surface of the tetrahedra is not a manifold: edge .* lies in 4"):
        Mesh(*_two_cubes([1.0, 1.0, 0]))
    with pytest.raises(ValueError, match=r"vertex \d+ is not a manifold vertex: its triangles form 2 separate fans"):
        Mesh(*_two_cubes([1.0, 1.0, 1.0]))


def test_2d_mesh_unchanged_by_the_generic_code(grid):
    assert grid.dim == 2 and repr(grid) == "Mesh(n_vertices=45, n_faces=64)"
    assert grid.boundary_facets.shape == (24, 2)
    assert dop.geometry.mesh.signed_areas is dop.geometry.mesh.signed_volumes


def test_tet_mesh_round_trips_through_npz_and_refuses_obj(tmp_path):
    m = block()
    m.save(tmp_path / "t.npz")
    assert Mesh.load(tmp_path / "t.npz") == m
    with pytest.raises(ValueError, match=r"a tetrahedral mesh is written as .npz \(.obj holds triangle surfaces\)"):
        m.save(tmp_path / "t.obj")
    assert not (tmp_path / "t.obj").exists()

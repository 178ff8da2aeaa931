"""Geometry checks before Triangle: every bad outline is a ValueError naming the offender.

Triangle itself segfaults on a pinched polygon, a zero-width spike and a hole identical to the outline
(measured with triangle 20250106: exit code 139 on all three), so those run in a subprocess here.
"""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from defop.geometry.planar import meshing, polygon
from defop.scene import shapes

SQ = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)
PINCHED = np.array([[0, 0], [1, 0], [1, 1], [2, 1], [2, 2], [1, 2], [1, 1], [0, 1]], float)
SPIKE = np.array([[0, 0], [1, 0], [1, 1], [0.5, 1], [0.5, 1.5], [0.5, 1], [0, 1]], float)


def square(x0, y0, s):
    return np.array([[x0, y0], [x0 + s, y0], [x0 + s, y0 + s], [x0, y0 + s]], float)


@pytest.mark.parametrize(
    "outer, holes, match",
    [
        (PINCHED, [], r"vertex 2 of the outer polygon at \(1, 1\) touches edge 5 of the same polygon"),
        (SPIKE, [], r"zero-width spike at vertex 4 \(0.5, 1.5\)"),
        # a spike whose way back is shorter than its way out
        ([[0, 0], [1, 0], [1, 1], [0.5, 1], [0.5, 1.5], [0.5, 1.2], [0.4, 1], [0, 1]], [], "spike at vertex 4"),
        (SQ, [SQ.copy()], "hole 0 is identical to the outer polygon"),
        (SQ, [SQ[::-1].copy()], "hole 0 is identical to the outer polygon"),
        (SQ, [square(0.5, 0.5, 3), square(1.5, 1.5, 1)], "hole 1 lies inside hole 0: nested holes"),
        (SQ, [square(5, 5, 1)], r"hole 0 is outside the outer polygon \(its vertex 0 at \(5, 5\)"),
        (SQ, [square(1, 1, 1), square(1.5, 1.5, 1)], "edge 1 of the hole 0 crosses edge 0 of the hole 1"),
        (SQ, [square(1, 1, 1), square(2, 1, 1)], "vertex 1 of the hole 0 at \\(2, 1\\) touches edge 0 of the hole 1"),
        (SQ, [square(0, 1, 1)], "vertex 0 of the hole 0 at \\(0, 1\\) touches edge 3 of the outer polygon"),
        ([[0, 0], [1, 1], [1, 0], [0, 1]], [], "edge 0 of the outer polygon crosses edge 2"),
        ([[0, 0], [1, 0], [2, 0]], [], r"zero-width spike at vertex 0 \(0, 0\)"),  # collinear: no area
        ([[0, 0], [1, 0], [1, 0], [0, 1]], [], r"outer polygon repeats point 1 at \(1, 0\)"),
    ],
)
def test_invalid_outlines_name_the_offender(outer, holes, match):
    with pytest.raises(ValueError, match=match):
        polygon.validate_polygon(outer, holes)
    with pytest.raises(ValueError, match=match):  # and the public entry point says the same
        shapes.from_polygon(outer, holes, handles=[[0.25, 0.25]], n_vertices=100)


def test_triangle_crash_candidates_raise_in_a_subprocess():
    """The three inputs that segfault Triangle give ValueErrors; the interpreter survives (exit code 0)."""
    code = textwrap.dedent(
        """
        import numpy as np
        from defop.scene import shapes
        SQ = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)
        cases = [
            ([[0, 0], [1, 0], [1, 1], [2, 1], [2, 2], [1, 2], [1, 1], [0, 1]], []),
            ([[0, 0], [1, 0], [1, 1], [0.5, 1], [0.5, 1.5], [0.5, 1], [0, 1]], []),
            (SQ, [SQ.copy()]),
        ]
        for outer, holes in cases:
            try:
                shapes.from_polygon(outer, holes, handles=[[0.25, 0.25]], n_vertices=200)
            except ValueError as e:
                print("ValueError:", e)
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("ValueError:") == 3


def test_nested_hole_no_longer_fills_the_outer_hole():
    """Before: a hole in a hole meshed with area 15.75 instead of 12; now it is rejected."""
    outer, big, small = square(0, 0, 4), square(1, 1, 2), square(1.5, 1.5, 1)
    with pytest.raises(ValueError, match="hole 1 lies inside hole 0"):
        meshing.triangulate(outer, [big, small])
    assert meshing.triangulate(outer, [big], max_area=0.1).areas.sum() == pytest.approx(12.0, rel=1e-12)


def test_hole_outside_the_outline_is_rejected_not_left_unused():
    with pytest.raises(ValueError, match="hole 0 is outside the outer polygon"):
        shapes.from_polygon(SQ, [square(6, 0, 1)], handles=[[1, 1]], n_vertices=200)


@pytest.mark.parametrize("size", [1e-59, 1e-12, 1e-6, 1.0, 1e6, 1e12, 1e59])
def test_tiny_and_huge_squares_mesh(size):
    """Tolerances are relative: a valid 1e-12 square is not "zero area" and meshes like a unit one."""
    S = square(0, 0, size)
    s = shapes.from_polygon(S, handles=[[0.5 * size, 0.5 * size]], n_vertices=100)
    assert s.mesh.areas.sum() == pytest.approx(size**2, rel=1e-12)
    assert 90 <= s.mesh.n_vertices <= 110
    assert np.array_equal(s.P, [[0.5 * size, 0.5 * size]])  # the handle is a vertex, exactly
    assert meshing.triangulate(S).areas.sum() == pytest.approx(size**2, rel=1e-12)


@pytest.mark.parametrize("size", [1e-300, 1e-61, 1e61, 1e200])
def test_squares_beyond_float_range_are_named_not_called_pinched(size):
    with pytest.raises(ValueError, match=re.escape(f"extent {size:.3g}") + " is outside the supported range .*rescale"):
        shapes.from_polygon(square(0, 0, size), handles=[[0.5 * size, 0.5 * size]], n_vertices=100)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"n_vertices": 1e8}, "n_vertices must lie between 3 and 1,000,000, got 100000000.0"),
        ({"n_vertices": 0}, "n_vertices must lie between 3 and 1,000,000, got 0"),
        ({"n_vertices": -5}, "n_vertices must lie between 3 and 1,000,000, got -5"),
        ({"n_vertices": np.nan}, "n_vertices must be an integer, got nan"),
        ({"n_vertices": 10.5}, "n_vertices must be an integer, got 10.5"),
        ({"n_vertices": True}, "n_vertices must be an integer, got True"),
        ({"max_area": -1}, "max_area must be a positive number, got -1"),
        ({"max_area": np.inf}, "max_area must be a positive number, got inf"),
        ({"max_area": 1e-12}, r"about 8e\+12 vertices .*\(use max_area >= 8e-06\)"),
    ],
)
def test_vertex_count_and_area_are_bounded(kw, match):
    with pytest.raises(ValueError, match=match):
        shapes.from_polygon(SQ, handles=[[1, 1]], **kw)


def test_load_rejects_bad_vertex_counts():
    for bad in (0, -1, 1e8, 10, 2.5, "many"):
        with pytest.raises(ValueError, match="n_vertices"):
            shapes.load("bar", n_vertices=bad)


def test_polygon_area_and_interior_helpers():
    assert polygon.polygon_area(SQ) == pytest.approx(16.0)
    assert polygon.polygon_area(SQ[::-1]) == pytest.approx(-16.0)
    assert polygon.points_in_polygon([[1, 1], [5, 5], [2, 2]], [SQ, square(1.5, 1.5, 1)]).tolist() == [
        True,
        False,
        False,
    ]
    assert polygon.distance_to_outline([[2, 1], [5, 2]], [SQ]) == pytest.approx([1.0, 1.0])
    assert polygon.touching_vertices([SQ], 1e-10) == [] and polygon.self_intersections([SQ]) == []


# --------------------------------------------------------------------------- property tests
@st.composite
def star_polygons(draw, min_n=4, max_n=40):
    """Star-shaped polygons around the origin: simple by construction (gaps < π, radii > 0)."""
    n = draw(st.integers(min_n, max_n))
    gaps = np.array(draw(st.lists(st.floats(1.0, 2.0), min_size=n, max_size=n)))
    radii = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=n, max_size=n)))
    scale = draw(st.sampled_from([1e-9, 1e-3, 1.0, 1e3]))
    t = draw(st.floats(0, 2 * np.pi)) + np.cumsum(gaps) / gaps.sum() * 2 * np.pi
    return scale * np.column_stack([radii * np.cos(t), radii * np.sin(t)])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(star_polygons())
def test_random_star_polygons_always_mesh(P):
    s = shapes.from_polygon(P, handles=[[0.0, 0.0]], n_vertices=150)
    assert np.all(s.mesh.areas > 0)
    assert np.array_equal(s.P, [[0.0, 0.0]])
    # the outline is resampled along the polygon's edges at the mesh spacing h (about 10% of the size at
    # 150 vertices): corners sharper than 20° are kept exactly, gentler ones cut by a chord of length ~h
    boundary = s.mesh.V[np.concatenate(s.mesh.boundary_loops())]
    assert polygon.distance_to_outline(boundary, [P]).max() <= 0.05 * polygon.diagonal(P)
    assert s.mesh.areas.sum() == pytest.approx(abs(polygon.polygon_area(P)), rel=0.1)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(star_polygons(min_n=5), st.data())
def test_random_pinched_polygons_always_raise(P, data):
    """A vertex moved onto a non-adjacent vertex or edge pinches the polygon: ValueError, never a crash."""
    n = len(P)
    i = data.draw(st.integers(0, n - 1))
    j = (i + data.draw(st.integers(2, n - 2))) % n  # not i, not a neighbour of i
    Q = P.copy()
    if data.draw(st.booleans()):
        Q[j] = P[i]  # touch a vertex
    else:
        k = (i + 1) % n
        if j == k or (j + 1) % n == i:
            Q[j] = P[i]
        else:
            Q[j] = 0.5 * (P[i] + P[k])  # touch the middle of edge i
    with pytest.raises(ValueError, match="touches|crosses|spike|zero area|repeats"):
        shapes.from_polygon(Q, handles=[[0.0, 0.0]], n_vertices=150)


def test_handles_on_near_and_outside_the_boundary():
    """Handles at least 1e-6 of the size inside: one on the boundary segfaulted Triangle once in a full test
    run, one 1e-9 inside gave 68 zero-area triangles."""
    unit, hole = square(0, 0, 1), square(0.4, 0.4, 0.2)
    cases = [
        ([[0.2, 0.2], [0.5, 0.4]], [hole], r"handle 1 at \(0.5, 0.4\) is on the boundary of the shape"),
        ([[0.5, 0.0]], [], r"handle 0 at \(0.5, 0\) is on the boundary of the shape \(nearest boundary point is 0"),
        ([[0.0, 0.0]], [], r"handle 0 at \(0, 0\) is on the boundary"),
        ([[1e-14, 0.5]], [], r"handle 0 at \(1e-14, 0.5\) is on the boundary .* 1e-14 away"),
        ([[-1e-14, 0.5]], [], r"handle 0 at \(-1e-14, 0.5\) is on the boundary"),  # within the tolerance
        ([[0.2, 0.2], [0.5, 0.5]], [hole], r"handle 1 at \(0.5, 0.5\) is outside the shape \(nearest boundary"),
    ]
    for handles, holes, match in cases:
        with pytest.raises(ValueError, match=match):
            shapes.from_polygon(unit, holes, handles=handles, n_vertices=200)
    with pytest.raises(ValueError, match=r"handle 0 at \(1e-09, 0.5\) is on the boundary .* at least 1.41e-06 inside"):
        shapes.from_polygon(unit, handles=[[1e-9, 0.5]], n_vertices=200)
    s = shapes.from_polygon(unit, [hole], handles=[[1e-5, 0.5], [0.5, 0.4 - 1e-5]], n_vertices=200)
    assert np.array_equal(s.P, [[1e-5, 0.5], [0.5, 0.4 - 1e-5]]) and np.all(s.mesh.areas > 0)

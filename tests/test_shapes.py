"""Shapes: polygons → meshes, the paper's models, user shapes from polygons and images, bad input."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.geometry import planar
from defop.scene import shapes

SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
HOLE = np.array([[0.4, 0.4], [0.6, 0.4], [0.6, 0.6], [0.4, 0.6]], float)

EXPECTED = {  # name: (default vertices, moving, fixed)
    "bar": (600, 1, 3),
    "u_shape": (800, 2, 4),
    "gingerbread": (1200, 5, 0),
    "aleph": (2900, 5, 0),
    "octopus": (4000, 9, 0),
    "crab": (2100, 10, 1),
    "dino": (1700, 2, 2),
}


def test_polygon_with_hole_areas_orientation_and_loops():
    s = shapes.from_polygon(SQUARE, [HOLE], handles=[[0.1, 0.1], [0.9, 0.9]], n_vertices=400)
    m = s.mesh
    assert np.all(dop.geometry.mesh.signed_areas(m.V, m.F) > 0)  # counter-clockwise
    assert m.areas.sum() == pytest.approx(1.0 - 0.04, rel=1e-12)  # polygon minus hole, exactly
    loops = m.boundary_loops()
    assert len(loops) == 2
    outer, inner = m.V[loops[0]], m.V[loops[1]]
    d_outer = np.minimum.reduce([outer[:, 0], 1 - outer[:, 0], outer[:, 1], 1 - outer[:, 1]])
    assert np.allclose(d_outer, 0, atol=1e-12)  # every outer-loop vertex lies on the square
    d_inner = np.minimum.reduce([inner[:, 0] - 0.4, 0.6 - inner[:, 0], inner[:, 1] - 0.4, 0.6 - inner[:, 1]])
    assert np.allclose(d_inner, 0, atol=1e-12)
    assert abs(planar.polygon_area(outer)) == pytest.approx(1.0)  # the loop walks around the whole outline


@pytest.mark.parametrize("name", shapes.names())
def test_named_shape(name):
    s = shapes.load(name)
    n, n_moving, n_fixed = EXPECTED[name]
    assert abs(s.mesh.n_vertices - n) <= 0.15 * n
    assert (s.n_moving, len(s.handles) - s.n_moving) == (n_moving, n_fixed)
    assert len(s.regions) == s.n_moving
    assert np.all(dop.geometry.mesh.signed_areas(s.mesh.V, s.mesh.F) > 0)
    # every handle is exactly a mesh vertex, inside the outline, and the outline is one simple polygon
    assert np.array_equal(s.P, s.mesh.V[s.handles])
    assert planar.polygon.points_in_polygon(s.P, s.outline).all()
    assert len(s.mesh.boundary_loops()) == len(s.outline)
    assert s.mesh.areas.sum() == pytest.approx(
        abs(planar.polygon_area(s.outline[0])) - sum(abs(planar.polygon_area(h)) for h in s.outline[1:]), rel=2e-2
    )


def test_load_is_deterministic_and_returns_copies():
    a, b = shapes.load("bar"), shapes.load("bar")
    assert a.mesh == b.mesh and np.array_equal(a.handles, b.handles)
    a.mesh.V[0] += 1.0
    assert shapes.load("bar").mesh.V[0, 0] == b.mesh.V[0, 0]


def test_n_vertices_is_configurable():
    s = shapes.load("bar", n_vertices=300)
    assert 250 <= s.mesh.n_vertices <= 350


def test_targets_puts_fixed_handles_at_rest():
    s = shapes.load("u_shape")
    Q = s.P_moving + 0.1
    T = s.targets(Q)
    assert np.array_equal(T[s.moving], Q) and np.array_equal(T[~s.moving], s.P[~s.moving])
    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        s.targets(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN"):
        s.targets(np.full((2, 2), np.nan))


def test_aleph_is_the_dejavu_glyph():
    s = shapes.load("aleph")
    assert "DejaVu" in s.description
    # the glyph's outline is a single loop whose bounding box is normalised to 1
    assert np.ptp(s.outline[0], axis=0).max() == pytest.approx(1.0)


def test_from_image_disc_and_annulus():
    yy, xx = np.mgrid[:200, :200]
    r = np.hypot(xx - 100, yy - 100)
    disc = (r < 60).astype(float)
    s = shapes.from_image(disc, n_vertices=500, size=1.0)
    # the silhouette is scaled so that its bbox diagonal is 1: a disc of radius 1/(2 sqrt 2)
    assert s.mesh.areas.sum() == pytest.approx(np.pi / 8, rel=0.03)
    assert len(s.mesh.boundary_loops()) == 1
    annulus = ((r < 80) & (r > 40)).astype(float)
    rgba = np.zeros((200, 200, 4))
    rgba[..., 3] = annulus
    a = shapes.from_image(rgba, n_vertices=600)
    assert len(a.mesh.boundary_loops()) == 2
    R = 1 / (2 * np.sqrt(2))
    assert a.mesh.areas.sum() == pytest.approx(np.pi * (R**2 - (R / 2) ** 2), rel=0.05)


def test_from_image_warns_when_it_drops_a_separate_region():
    yy, xx = np.mgrid[:200, :300]
    two = ((np.hypot(xx - 80, yy - 100) < 60) | (np.hypot(xx - 230, yy - 100) < 30)).astype(float)
    message = r"2 separate regions; kept the largest, dropped 1 .*has 2[45]\.\d% of its area"
    with pytest.warns(UserWarning, match=message):
        s = shapes.from_image(two, n_vertices=400, size=1.0)
    assert len(s.mesh.boundary_loops()) == 1
    r = np.hypot(xx - 150, yy - 100)
    island = ((r < 90) & (r > 50)) | (r < 20)  # an annulus with a disc inside its hole
    with pytest.warns(UserWarning, match="dropped 1"):
        a = shapes.from_image(island.astype(float), n_vertices=400)
    assert len(a.mesh.boundary_loops()) == 2


def test_from_image_png_file(tmp_path):
    from matplotlib.image import imsave

    yy, xx = np.mgrid[:120, :160]
    img = np.ones((120, 160, 3))
    img[(abs(xx - 80) < 50) & (abs(yy - 60) < 30)] = 0.0  # a dark rectangle on white
    imsave(tmp_path / "rect.png", img)
    s = shapes.from_image(tmp_path / "rect.png", n_vertices=300, size=np.hypot(100, 60))
    assert s.mesh.areas.sum() == pytest.approx(100 * 60, rel=0.03)


# ---------------------------------------------------------------- bad input gets a clear ValueError
def test_self_intersecting_polygon():
    bowtie = np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float)
    with pytest.raises(ValueError, match="self-intersecting: edge 0 of the outer polygon crosses edge 2"):
        shapes.from_polygon(bowtie, handles=[[0.1, 0.5]])


def test_hole_crossing_the_outline():
    with pytest.raises(ValueError, match="self-intersecting.*hole 0"):
        planar.triangulate(SQUARE, [HOLE + 0.5])


def test_too_few_points():
    with pytest.raises(ValueError, match="2 points; a polygon needs at least 3"):
        planar.triangulate(np.array([[0, 0], [1, 0]], float))


def test_nan_coordinates():
    bad = SQUARE.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        planar.triangulate(bad)


def test_handle_outside_the_shape():
    msg = r"handle 1 at \(1.31, 0.5\) is outside the shape \(nearest boundary point is 0.31 away\)"
    with pytest.raises(ValueError, match=msg):
        shapes.from_polygon(SQUARE, handles=[[0.5, 0.5], [1.31, 0.5]])
    with pytest.raises(ValueError, match="handle 0 .* is outside the shape"):  # inside the hole is outside
        shapes.from_polygon(SQUARE, [HOLE], handles=[[0.5, 0.5]])


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(ValueError, match="unknown shape 'teapot'; known shapes: bar, u_shape, gingerbread, aleph"):
        shapes.load("teapot")


def test_image_without_foreground():
    with pytest.raises(ValueError, match="no foreground"):
        shapes.from_image(np.zeros((50, 50)))


def test_bad_region():
    with pytest.raises(ValueError, match="unknown kind 'square'"):
        shapes.from_polygon(SQUARE, handles=[[0.5, 0.5]], regions=[{"kind": "square"}], n_vertices=100)


# ---------------------------------------------------------------- images: one foreground rule for every layout
def _dark_rectangle_on_white():
    yy, xx = np.mgrid[:120, :160]
    grey = np.ones((120, 160))
    grey[(abs(xx - 80) < 50) & (abs(yy - 60) < 30)] = 0.0
    return grey


def test_same_picture_same_mesh_in_every_layout(tmp_path):
    """Before: a 2-D array or an L-mode PNG meshed the background, an RGB copy the shape."""
    from PIL import Image

    grey = _dark_rectangle_on_white()
    rgb = np.repeat(grey[..., None], 3, axis=2)
    u8 = (grey * 255).astype(np.uint8)
    Image.fromarray(u8, mode="L").save(tmp_path / "l.png")
    Image.fromarray(np.repeat(u8[..., None], 3, axis=2), mode="RGB").save(tmp_path / "rgb.png")
    layouts = {
        "grey": grey,
        "grey uint8": u8,
        "bool": grey > 0.5,
        "rgb": rgb,
        "rgba opaque": np.concatenate([rgb, np.ones((120, 160, 1))], axis=2),
        "L png": tmp_path / "l.png",
        "RGB png": tmp_path / "rgb.png",
    }
    meshes = {k: shapes.from_image(v, n_vertices=300, size=np.hypot(100, 60)).mesh for k, v in layouts.items()}
    for k, m in meshes.items():
        assert m == meshes["grey"], k
    assert meshes["grey"].areas.sum() == pytest.approx(100 * 60, rel=0.03)  # the rectangle, not the background
    explicit = shapes.from_image(grey, n_vertices=300, size=np.hypot(100, 60), foreground="dark").mesh
    assert explicit == meshes["grey"]


def test_light_on_dark_picture_is_found_from_the_border():
    inverted = 1.0 - _dark_rectangle_on_white()
    s = shapes.from_image(inverted, n_vertices=300, size=np.hypot(100, 60))
    assert s.mesh.areas.sum() == pytest.approx(100 * 60, rel=0.03)


@pytest.mark.parametrize(
    "image, kw, match",
    [
        (np.zeros((50, 50, 2)), {}, r"\(H,W,3\) RGB or \(H,W,4\) RGBA; got shape \(50, 50, 2\)"),
        (np.zeros((50, 50), complex), {}, "real numbers .* got dtype complex128"),
        (np.full((50, 50), 3.0), {}, r"float image values must lie in \[0,1\], got \[3, 3\]"),
        (np.full((50, 50), np.nan), {}, "NaN"),
        (np.zeros((50, 50)), {}, r"no foreground \(every pixel is the same colour"),
        (np.ones((50, 50)), {}, r"no foreground \(every pixel is the same colour"),
        (
            np.zeros((50, 50)),
            {"threshold": 0.5},
            "no foreground .* assumed the shape is light on a dark background .*judged from the border",
        ),
        (
            np.ones((50, 50)),
            {"threshold": 0.5},
            "no foreground .* assumed the shape is dark on a light background .*judged from the border",
        ),
        (np.zeros((50, 50)), {"foreground": "light"}, r"no foreground .*\(foreground='light'\)"),
        (np.zeros((50, 50)), {"foreground": "alpha"}, r"foreground='alpha' needs an \(H,W,4\) RGBA image"),
        (np.zeros((50, 50)), {"foreground": "purple"}, "foreground must be one of"),
        (np.zeros((50, 50)), {"threshold": 1.5}, "threshold must lie strictly between 0 and 1"),
    ],
)
def test_bad_images(image, kw, match):
    with pytest.raises(ValueError, match=match):
        shapes.from_image(image, **kw)


def test_shapes_lists_what_shape_users_need_and_planar_the_polygon_helpers():
    assert set(shapes.__all__) == {
        "Shape",
        "load",
        "names",
        "from_polygon",
        "from_image",
        "image_frame",
        "from_surface",
        "default_vertices",
        "REGION_KINDS",
        "MAX_VERTICES",
    }
    for name in shapes.__all__:
        assert hasattr(shapes, name), name
    for name in ("triangulate", "polygon_area"):
        assert callable(getattr(planar, name)), name
    for name in ("points_in_polygon", "validate_polygon", "self_intersections"):
        assert callable(getattr(planar.polygon, name)), name
    for name in ("image_outline", "implicit_outline", "capsule", "read_image", "load_image"):
        assert callable(getattr(planar.outlines, name)), name
    assert set(shapes.names()) == set(dop.scene.models.CATALOGUE)


def test_regions_are_classes_that_still_read_like_dicts():
    s = shapes.load("octopus", n_vertices=600)
    assert all(isinstance(r, dop.scene.regions.Mixture) for r in s.regions[:8])
    assert s.regions[0]["kind"] == "mixture" and s.regions[8]["radius"] == 0.12
    assert dop.scene.regions.as_region(s.regions[0].to_dict()) == s.regions[0]


def test_shape_handle_indices_are_integers_or_a_mask():
    mesh = shapes.load("bar", n_vertices=200).mesh
    one = [{"kind": "disc", "radius": 0.1}]
    with pytest.raises(ValueError, match=r"handle 0 is 1.7, not an integer vertex index"):
        shapes.Shape("s", mesh, [1.7, 2.9], [True, False], one)
    assert shapes.Shape("s", mesh, [1.0, 2.0], [True, False], one).handles.tolist() == [1, 2]
    mask = np.zeros(mesh.n_vertices, bool)
    mask[[3, 5]] = True
    assert shapes.Shape("s", mesh, mask, [True, False], one).handles.tolist() == [3, 5]
    with pytest.raises(ValueError, match="boolean handle mask needs one entry per vertex"):
        shapes.Shape("s", mesh, mask[:10], [True, False], one)


def test_moving_flags_are_booleans_not_indices():
    with pytest.raises(ValueError, match="moving must be one True/False flag per handle"):
        shapes.from_polygon(SQUARE, handles=[[0.2, 0.2], [0.8, 0.8]], moving=[0, 2], n_vertices=100)
    s = shapes.from_polygon(SQUARE, handles=[[0.2, 0.2], [0.8, 0.8]], moving=[1, 0], n_vertices=100)
    assert s.moving.tolist() == [True, False]

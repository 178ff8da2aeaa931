"""Pictures: one rule for which pixels are the shape (colour pictures keep their area), the dropped-regions
warning, and a page with the picture on it from ``to_html(op, path, shape=..., image=...)`` alone.

The pictures are generated: stars and rings of random colours on random backgrounds, antialiased (8 x 8 samples a
pixel), 8-bit, grey, RGB, opaque RGBA or RGBA with a transparent background, dark on light and light on dark.
Their drawn area is known in closed form.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

import defop as dop
from defop.editor import export
from defop.geometry.mesh import signed_areas
from defop.geometry.planar.outlines import foreground, image_outline
from defop.geometry.planar.silhouette import otsu_level, silhouette

#: the meshed area of a generated picture is within this fraction of the drawn shape's area
AREA_TOLERANCE = 0.03
#: least colour distance (RGB, in [0, sqrt 3]) between a generated shape and its background
MIN_CONTRAST = 0.25


def _coverage(inside, H, W, ss=8):
    """(H,W) share of each pixel inside ``inside(x, y)`` (x = column, y = row), from ss x ss samples a pixel."""
    o = (np.arange(ss) + 0.5) / ss - 0.5
    X, Y = np.meshgrid((np.arange(W)[:, None] + o).ravel(), (np.arange(H)[:, None] + o).ravel())
    return inside(X, Y).reshape(H, ss, W, ss).mean(axis=(1, 3))


def _star(cx, cy, r0, r1, k, phase=0.0, hole=0.0):
    """A smooth star r(a) = m + h cos(k (a - phase)), m = (r0 + r1)/2, h = (r1 - r0)/2, less a central disc of
    radius ``hole``: the test ``inside(x, y)`` and its area π (m² + h²/2) − π hole²."""
    m, h = (r0 + r1) / 2, (r1 - r0) / 2

    def inside(X, Y):
        r, a = np.hypot(X - cx, Y - cy), np.arctan2(Y - cy, X - cx)
        return (r < m + h * np.cos(k * (a - phase))) & (r >= hole)

    return inside, np.pi * (m * m + h * h / 2 - hole * hole)


def _colours(rng, light_on_dark):
    """A shape colour and a background colour at least MIN_CONTRAST apart; the shape the lighter one (by grey)
    when ``light_on_dark``."""
    while True:
        a, b = rng.random(3), rng.random(3)
        if np.linalg.norm(a - b) >= MIN_CONTRAST and (a.mean() > b.mean()) == light_on_dark:
            return a, b


def _picture(seed):
    """A generated picture, (H,W[,c]) uint8, the drawn area in pixels, and what it is."""
    rng = np.random.default_rng(seed)
    H, W = rng.integers(90, 150, size=2)
    R = min(H, W) / 2 - 6
    r1 = rng.uniform(0.6, 1.0) * R
    inside, area = _star(
        W / 2 + rng.uniform(-3, 3),
        H / 2 + rng.uniform(-3, 3),
        rng.uniform(0.45, 0.8) * r1,
        r1,
        int(rng.integers(3, 8)),
        rng.uniform(0, 2 * np.pi),
        hole=rng.uniform(6, 12) if seed % 4 == 3 else 0.0,
    )
    c = _coverage(inside, H, W)[..., None]
    shape_colour, background = _colours(rng, light_on_dark=bool(seed % 2))
    layout = ("rgb", "rgba opaque", "rgba transparent", "grey")[seed // 2 % 4]
    if layout == "grey":
        shape_colour, background = shape_colour.mean(), background.mean()
        if abs(shape_colour - background) < MIN_CONTRAST / 2:
            shape_colour = background + np.copysign(MIN_CONTRAST, shape_colour - background)
            shape_colour = float(np.clip(shape_colour, 0, 1))
    img = background + c * (shape_colour - background)
    if layout == "rgba opaque":
        img = np.concatenate([img, np.ones_like(c)], axis=2)
    elif layout == "rgba transparent":  # the shape's colour everywhere, alpha the coverage
        img = np.concatenate([np.broadcast_to(shape_colour, img.shape), c], axis=2)
    elif layout == "grey":
        img = img[..., 0]
    what = f"seed {seed}: {layout}, {'light on dark' if seed % 2 else 'dark on light'}"
    return np.round(img * 255).astype(np.uint8), area, what


def _meshed_area_px(shape, image, **kw):
    """The area of the shape's mesh in the picture's pixels."""
    V = dop.shapes.image_frame(image, shape, **kw)(shape.mesh.V)
    return abs(signed_areas(V, shape.mesh.F).sum())


@pytest.mark.parametrize("seed", range(16))
def test_generated_pictures_keep_their_area(seed):
    image, drawn, what = _picture(seed)
    shape = dop.shapes.from_image(image, n_vertices=300)
    meshed = _meshed_area_px(shape, image)
    assert abs(meshed / drawn - 1) < AREA_TOLERANCE, f"{what}: meshed {meshed:.0f} px², drawn {drawn:.0f} px²"


def _shaded_star():
    """A star shaded from dark green to light green, left to right, on white: 8-bit RGB, and its drawn area."""
    H, W = 120, 140
    inside, area = _star(70, 60, 25, 50, 5)
    c = _coverage(inside, H, W)[..., None]
    t = np.clip((np.arange(W) - 20) / 100, 0, 1)[None, :, None]
    fill = np.array([0.1, 0.4, 0.1]) * (1 - t) + np.array([0.58, 0.98, 0.40]) * t
    return np.round((1 + c * (fill - 1)) * 255).astype(np.uint8), area


def test_a_shaded_colour_picture_keeps_its_area():
    """Before, the default (foreground = 1 − mean RGB above 0.5) dropped the star's light half: 23.5% of its area."""
    image, drawn = _shaded_star()
    before = dop.shapes.from_image(image, threshold=0.5, n_vertices=600)
    assert _meshed_area_px(before, image, threshold=0.5) / drawn - 1 < -0.2  # today's meaning of threshold=0.5
    now = dop.shapes.from_image(image, n_vertices=600)
    assert abs(_meshed_area_px(now, image) / drawn - 1) < 0.01


def test_an_explicit_threshold_keeps_its_meaning():
    image, _, _ = _picture(2)
    img = image / 255.0
    for t in (0.2, 0.5, 0.7):
        fg, _ = foreground(img)
        try:
            mask, _ = silhouette(img, t)
        except ValueError:
            assert (fg > t).all() or not (fg > t).any()
            continue
        np.testing.assert_array_equal(mask, fg > t)


def test_a_binary_picture_meshes_as_before():
    """On a 0/1 picture every threshold in (0,1) cuts the same pixels: the mesh is the one of threshold=0.5."""
    yy, xx = np.mgrid[:200, :300]
    star = np.hypot(xx - 150, yy - 100) < 70 + 20 * np.cos(5 * np.arctan2(yy - 100, xx - 150))
    for picture in (star, ~star, star.astype(np.uint8) * 255):
        assert (
            dop.shapes.from_image(picture, n_vertices=300).mesh
            == dop.shapes.from_image(picture, threshold=0.5, n_vertices=300).mesh
        )


def test_a_shape_cut_by_the_border_is_still_the_shape():
    """The shape is the side that touches the border less, whatever the border's colour statistics."""
    inside, _ = _star(0, 60, 30, 50, 4)  # centred on the left edge: half a star
    c = _coverage(inside, 120, 140)[..., None]
    image = np.array([0.9, 0.2, 0.3]) * c + np.array([0.2, 0.3, 0.9]) * (1 - c)
    mask, _ = silhouette(image)
    clear = np.abs(c[..., 0] - 0.5) > 0.1  # Otsu's level is about, not exactly, halfway
    np.testing.assert_array_equal(mask[clear], c[..., 0][clear] > 0.5)
    assert abs(mask.sum() / np.count_nonzero(c > 0.5) - 1) < 0.01


def test_otsu_level_is_scikit_images():
    """The core's Otsu threshold (numpy only) is skimage.filters.threshold_otsu's, bin for bin."""
    threshold_otsu = pytest.importorskip("skimage.filters").threshold_otsu
    rng = np.random.default_rng(7)
    for _ in range(30):
        x = rng.random(int(rng.integers(2, 2000))) ** rng.uniform(0.2, 5)
        assert otsu_level(x) == threshold_otsu(x)
    assert otsu_level(np.array([0.0, 1.0, 1.0, 0.0])) == threshold_otsu(np.array([0.0, 1.0, 1.0, 0.0]))


def test_an_almost_opaque_alpha_channel_is_not_the_shape():
    """An RGBA picture whose alpha is 1 but for a few 254/255 pixels: the shape is the drawn one, in colour."""
    image, drawn, _ = _picture(0)
    rgba = np.concatenate([image, np.full((*image.shape[:2], 1), 255, np.uint8)], axis=2)
    rgba[::7, ::5, 3] = 254
    mask, assumed = silhouette(rgba / 255.0)
    assert "colour" in assumed and abs(mask.sum() / drawn - 1) < AREA_TOLERANCE, assumed


# ------------------------------------------------------------------------ the dropped-regions warning
def test_the_dropped_regions_warning_names_threshold_and_the_area_lost():
    yy, xx = np.mgrid[:200, :300]
    two = (np.hypot(xx - 80, yy - 100) < 60) | (np.hypot(xx - 230, yy - 100) < 30)
    with pytest.warns(UserWarning) as record:
        image_outline(two.astype(float))
    message = str(record[0].message)
    assert "threshold=" in message, message
    lost = float(re.search(r"(\d+\.\d)% of the foreground's area is lost", message).group(1))
    assert lost == pytest.approx(100 * 30**2 / (60**2 + 30**2), abs=0.5), message  # 20% of the foreground


# ------------------------------------------------------------------------ the page places the picture itself
@pytest.fixture(scope="module")
def picture_op(tmp_path_factory):
    """A shaded star as an RGB PNG file, its shape and a small operator."""
    from PIL import Image

    image, _ = _shaded_star()
    path = tmp_path_factory.mktemp("pictures") / "star.png"
    Image.fromarray(image).save(path)
    shape = dop.shapes.from_image(path, n_vertices=150, n_auto_handles=2)
    op, _ = dop.train(shape, m=12, progress=False, n_jobs=1, rounds=1, cache=False)
    return image, path, shape, op


def test_image_frame_maps_the_outline_back_onto_the_picture(picture_op):
    image, path, shape, _ = picture_op
    outer, _ = image_outline(image)
    to_pixels = dop.shapes.image_frame(path, shape)
    back = to_pixels(shape.outline[0])
    expected = np.column_stack([outer[:, 0], image.shape[0] - 1 - outer[:, 1]])  # y up -> row down
    np.testing.assert_allclose(np.sort(back, axis=0), np.sort(expected, axis=0), atol=1e-9)


def test_image_frame_agrees_with_the_masks_frame():
    """On a binary picture, the frame of view.warp.image_to_mesh_frame, within a pixel (it matches the mesh's
    bounding box to the mask's pixel edges, not to the outline)."""
    yy, xx = np.mgrid[:160, :220]
    mask = np.hypot(xx - 110, yy - 80) < 50 + 15 * np.cos(3 * np.arctan2(yy - 80, xx - 110))
    shape = dop.shapes.from_image(mask, n_vertices=300, size=2.5)
    _, old = dop.view.warp.image_to_mesh_frame(mask, shape.mesh)
    assert np.abs(dop.shapes.image_frame(mask, shape)(shape.mesh.V) - old(shape.mesh.V)).max() < 0.75


def test_to_html_places_the_picture_from_the_shape(picture_op, tmp_path, monkeypatch):
    image, path, shape, op = picture_op
    sent = []
    encode = export.encode_payload
    monkeypatch.setattr(export, "encode_payload", lambda p: sent.append(p) or encode(p))
    page = export.to_html(op, tmp_path / "page.html", shape=shape, image=path)
    uv, size = sent[0]["uv"], sent[0]["image_size"]
    V_px = dop.shapes.image_frame(image, shape)(shape.mesh.V)
    assert size == [image.shape[1], image.shape[0]]
    np.testing.assert_allclose(uv * size - 0.5, V_px, atol=1e-3)
    given = export.to_html(op, tmp_path / "given.html", shape=shape, image=image, image_frame=V_px)
    assert given.read_bytes() == page.read_bytes()


def test_to_html_picture_errors_say_what_to_pass(picture_op, tmp_path):
    image, path, shape, op = picture_op
    with pytest.raises(ValueError, match=r"image= needs shape= .*or image_frame="):
        export.to_html(op, tmp_path / "a.html", image=path)
    other = dop.shapes.from_image(image, threshold=0.3, n_vertices=150, n_auto_handles=2)
    with pytest.raises(ValueError, match=r"not the outline of shape .*threshold=.*image_frame="):
        dop.shapes.image_frame(image, other)
    frame = dop.shapes.image_frame(image, other, threshold=0.3)  # the same rule as from_image: the same frame
    assert np.abs(frame(other.outline[0])[:, 1] - image.shape[0] / 2).max() < image.shape[0] / 2
    u_shape = dop.shapes.load("u_shape", n_vertices=300)
    with pytest.raises(ValueError, match="not the outline of shape 'u_shape'"):
        dop.shapes.image_frame(image, u_shape)
    assert not (tmp_path / "a.html").exists()


# ------------------------------------------------------------------------ bad pictures: clear errors
@pytest.mark.parametrize(
    "image, kw, match",
    [
        (np.full((40, 50, 3), 0.3), {}, r"no foreground \(every pixel is the same colour"),
        (np.ones((40, 50)), {"threshold": 0.5}, r"no foreground \(no pixel above threshold=0.5; lower it"),
        (np.zeros((40, 50)), {"foreground": "dark", "threshold": 0.5}, r"all foreground .*threshold=0.5; raise it"),
        (np.zeros((40, 50, 4)), {"foreground": "alpha"}, r"no foreground \(every pixel is the same value"),
        (np.eye(40), {"threshold": 0.0}, r"threshold must lie strictly between 0 and 1 \(or None"),
        (
            np.random.default_rng(0).integers(250, 256, (40, 50, 3), dtype=np.uint8),
            {},
            r"no foreground \(every pixel is the same colour within 0.0\d+, less than MIN_CONTRAST .*threshold=",
        ),
    ],
    ids=["one colour", "none above threshold", "all above threshold", "transparent", "threshold 0", "noise"],
)
def test_bad_pictures(image, kw, match):
    with pytest.raises(ValueError, match=match):
        dop.shapes.from_image(image, **kw)


def test_a_file_that_is_not_a_picture(tmp_path, picture_op):
    _, _, shape, op = picture_op
    junk = tmp_path / "notes.png"
    junk.write_text("not a picture")
    with pytest.raises(ValueError, match=r"notes.png is not an image Pillow can read"):
        dop.shapes.from_image(junk)
    with pytest.raises(ValueError, match=r"notes.png is not an image Pillow can read"):
        export.to_html(op, tmp_path / "b.html", shape=shape, image=junk)
    assert not (tmp_path / "b.html").exists()


def test_pictures_warn_nothing_when_one_region():
    image, _, _ = _picture(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image_outline(image)


@pytest.mark.browser
def test_the_page_of_a_picture_shape_is_textured_and_drags_in_chromium(picture_op, tmp_path):
    """to_html(op, path, shape=, image=path) only: the page draws the picture (WebGL) and the handle follows."""
    from test_browser_editor import chromium_page, mouse_drag

    image, path, shape, op = picture_op
    page_path = export.to_html(op, tmp_path / "star.html", shape=shape, image=path)
    with chromium_page() as page:
        page.goto(page_path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        ready = page.evaluate("() => window.defopEditor.imageReady")
        text = page.evaluate("() => window.defopEditor.ui.readout.textContent")
        end = mouse_drag(page, "window.defopEditor", 30, -20)
        Q = np.array(page.evaluate("() => Array.from(window.defopEditor.st.Q)")).reshape(-1, 2)
        errors = page.errors
    assert not errors, errors
    assert ready is True and f"picture {image.shape[1]} × {image.shape[0]} px: textured (WebGL)" in text, text
    np.testing.assert_allclose(Q[0], end, atol=1e-12)

"""Hostile input, second round (issue 26): every class gets a clear error naming the argument, or a right answer.

Each test holds an instance measured on main (7c4dc5f) in its docstring: what it did before the fix.
"""

from __future__ import annotations

import io
import os
import struct
import warnings
import zipfile
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

import defop as dop
from defop import config
from defop import options as opt
from defop.analysis import peers as pe
from defop.geometry.mesh import MAX_FILE_ELEMENTS, read_mesh, write_mesh
from defop.geometry.planar.outlines import load_image
from defop.view import warp

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=150)


# ------------------------------------------------------------------------------------------------ options
@pytest.mark.parametrize("value", [0.5, np.float64(2.0), [1.0], [[1.0, 2.0]], [1.0, 2.0, 3.0], "ab", [1j, 0]])
def test_a_point_is_two_coordinates_never_a_broadcast_scalar(value):
    with pytest.raises(ValueError, match=r"^q must be "):
        opt.point("q", value)
    np.testing.assert_array_equal(opt.point("q", (1, 2)), [1.0, 2.0])


@pytest.mark.parametrize("value", [0.5, [0.5, 0.5], np.zeros((2, 3)), np.zeros((1, 2, 2)), [[np.nan, 0.0]]])
def test_points_are_n_by_2_and_finite(value):
    with pytest.raises(ValueError, match=r"^P (must be an array of shape \(n, 2\)|has a NaN)"):
        opt.points("P", value)


def test_n_jobs_above_the_cpu_count_is_capped_with_a_warning():
    """train(n_jobs=1000) started 1000 worker processes on 2 cores."""
    cores = opt.cpu_count()
    with pytest.warns(RuntimeWarning, match=rf"n_jobs=1000 is more than the {cores} cores of this machine"):
        assert opt.n_jobs(1000) == cores
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert opt.n_jobs(cores) == cores and opt.n_jobs(-1) == -1


def test_train_caps_n_jobs_where_it_starts_workers(bar, monkeypatch, tmp_path):
    monkeypatch.setenv("DEFOP_CACHE", "off")
    seen = []

    def fake_parallel_map(fn, items, n_jobs=None, show=False, desc=""):
        seen.append(n_jobs)
        return fn(list(items))  # fn takes a chunk; one chunk, in this process

    monkeypatch.setattr(dop.training.batch, "parallel_map", fake_parallel_map)
    with pytest.warns(RuntimeWarning, match="n_jobs=1000 is more than"), warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=dop.variational.solver.NotConvergedWarning)
        dop.train(bar, basis="linear", m=4, seed=0, progress=False, n_jobs=1000, rounds=1, cache=False)
    assert seen and all(n == opt.cpu_count() for n in seen)


@pytest.mark.parametrize("value", [5, None, b"t", ["t"]])
def test_text_must_be_a_string(value):
    with pytest.raises(ValueError, match=r"^title must be a string, got "):
        opt.text("title", value)


# ------------------------------------------------------------------------------------------------ peers
@pytest.mark.parametrize("iterations", [-5, 0, 2.5, "10", np.inf])
def test_peer_iteration_counts_are_positive_integers(bar, iterations):
    """ARAP iterations of -5 were accepted; bbw's max_iter 0 or -1 silently used libigl's default."""
    with pytest.raises(ValueError, match=r"^iterations must be an integer >= 1, got "):
        pe.make_peer(bar, "arap", iterations=iterations)
    with pytest.raises(ValueError, match=r"^max_iter must be an integer >= 1, got "):
        pe.bbw_precompute(bar.mesh, bar.handles, max_iter=iterations)


@pytest.mark.parametrize("alpha", [1e3, 1e308, np.inf, np.nan, 0.0, -1.0, "1"])
def test_mls_weight_exponent_is_bounded_never_nan(bar, alpha):
    """alpha = 1e3, 1e308 or inf gave NaN vertices."""
    with pytest.raises(ValueError, match=rf"^alpha must be a positive number <= {pe.MAX_ALPHA}, got "):
        pe.make_peer(bar, "mls-rigid", alpha=alpha)


def test_mls_weights_that_overflow_within_the_bound_are_named():
    V = np.array([[0.0, 0.0], [1e-7, 0.0], [1.0, 1.0]])
    P = np.array([[1e-7 + 1e-9, 0.0], [1.0, 0.0]])
    with pytest.raises(ValueError, match=r"^alpha = 50.0 is too large for these handle distances"):
        pe.mls_precompute(V, P, alpha=50.0)
    pre = pe.mls_precompute(V, P, alpha=1.0)
    assert np.isfinite(pe.mls_evaluate(pre, P)).all()


def test_biharmonic_coordinates_name_collinear_handles(bar):
    V = bar.mesh.V
    row = np.flatnonzero(np.abs(V[:, 1] - V[:, 1].min()) < 1e-12)[:4]  # vertices on the bottom edge
    assert len(row) >= 3
    with pytest.raises(ValueError, match=r"^biharmonic coordinates need handles that are not all on one line"):
        pe.biharmonic_precompute(bar.mesh, row)


def test_biharmonic_k_3_is_a_clear_error(bar):
    """libigl returns an empty matrix for k = 3: 'libigl biharmonic_coordinates failed (returned shape (0, 0))'."""
    with pytest.raises(ValueError, match=r"^k = 3 \(triharmonic\) is not available"):
        pe.biharmonic_precompute(bar.mesh, bar.handles, k=3)
    with pytest.raises(ValueError, match=r"^k must be an integer >= 1, got 0"):
        pe.biharmonic_precompute(bar.mesh, bar.handles, k=0)
    W = pe.biharmonic_precompute(bar.mesh, bar.handles, k=2)
    np.testing.assert_allclose(W @ bar.P, bar.mesh.V, atol=1e-8)  # linear precision: W P = V


@pytest.mark.parametrize("kind", ["tps", "mls-rigid"])
@pytest.mark.parametrize("Q", [0.5, [0.5, 0.5, 0.5], "Q", [[1j, 0]]])
def test_peers_refuse_scalars_and_strings_for_q(bar, kind, Q):
    peer = pe.make_peer(bar, kind)
    with pytest.raises(ValueError, match=r"^Q must "):
        peer(Q)


# ------------------------------------------------------------------------------------------------ shapes
def test_handles_1e_13_apart_are_named_not_counted_as_degenerate_triangles():
    """Gave '150 degenerate (zero-area) triangles, first is triangle ...'."""
    with pytest.raises(ValueError, match=r"^handles 0 and 1 are 1e-13 apart; merge them or move one"):
        dop.shapes.from_polygon(SQUARE, handles=[[0.5, 0.5], [0.5 + 1e-13, 0.5]], n_vertices=200)
    with pytest.raises(ValueError, match=r"^handles 1 and 2 coincide; merge them or move one"):
        dop.shapes.from_polygon(SQUARE, handles=[[0.2, 0.2], [0.5, 0.5], [0.5, 0.5]], n_vertices=200)
    shape = dop.shapes.from_polygon(SQUARE, handles=[[0.5, 0.5], [0.5 + 1e-4, 0.5]], n_vertices=200)
    assert len(shape.handles) == 2


@pytest.fixture(scope="module")
def blob():
    img = np.zeros((40, 60))
    img[10:30, 10:50] = 1.0
    return img


@pytest.mark.parametrize("count", [0, -1, 2.5, "2"])
def test_an_automatic_handle_count_of_0_is_an_error(blob, count):
    """n_auto_handles=0 gave one handle."""
    with pytest.raises(ValueError, match=r"^n_auto_handles must be an integer >= 1 and <= 100, got "):
        dop.shapes.from_image(blob, n_auto_handles=count, n_vertices=100)
    assert len(dop.shapes.from_image(blob, n_auto_handles=3, n_vertices=100).handles) == 3


@pytest.mark.parametrize("size", [1e300, 1e-300, 1e100])
def test_from_image_size_out_of_the_meshable_range(blob, size):
    """size=1e300 said 'the shape is too thin to place handles automatically'."""
    with pytest.raises(ValueError, match=r"^size must be a positive number in \[1e-60, 1e\+60\]"):
        dop.shapes.from_image(blob, size=size)


# ------------------------------------------------------------------------------------------------ images
@pytest.fixture(scope="module")
def png_bytes():
    buf = io.BytesIO()
    Image.fromarray((np.arange(40 * 60).reshape(40, 60) % 251).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _png_declaring(png, w, h):
    """The same PNG with its IHDR saying w × h (CRC fixed, pixels not)."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    chunk = struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    return png[:8] + chunk + png[33:]


@pytest.mark.parametrize("w, h", [(60_000, 60_000), (12_000, 12_000)])
def test_a_huge_declared_image_is_refused_by_pillows_own_limit(tmp_path, png_bytes, w, h):
    """Pillow's DecompressionBombError, or its warning followed by a MemoryError."""
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_declaring(png_bytes, w, h))
    with pytest.raises(
        ValueError,
        match=rf"^image file {path} declares {w * h:,} pixels, more than Pillow's "
        r"decompression-bomb limit PIL.Image.MAX_IMAGE_PIXELS = 89,478,485",
    ):
        load_image(path)


def test_the_limit_is_pillows_setting(tmp_path, png_bytes, monkeypatch):
    path = tmp_path / "small.png"
    path.write_bytes(png_bytes)
    assert load_image(path).shape == (40, 60)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)
    with pytest.raises(ValueError, match=r"declares 2,400 pixels, more than .* = 1,000"):
        load_image(path)


def test_truncated_and_foreign_image_files_are_named(tmp_path, png_bytes):
    cut = tmp_path / "cut.png"
    cut.write_bytes(png_bytes[: len(png_bytes) // 2])
    with pytest.raises(ValueError, match=rf"^image file {cut} is truncated or corrupt"):
        load_image(cut)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image" * 10)
    with pytest.raises(ValueError, match=rf"^image file {junk} is not an image Pillow can read"):
        dop.shapes.from_image(junk)


def test_an_image_path_may_be_bytes(tmp_path, png_bytes):
    """A bytes path said 'an image must hold real numbers ..., got dtype |S..'."""
    path = tmp_path / "p.png"
    path.write_bytes(png_bytes)
    np.testing.assert_array_equal(load_image(os.fsencode(path)), load_image(path))
    with pytest.raises(ValueError, match=r"^no such image file: "):
        load_image(b"/no/such/file.png")
    with pytest.raises(ValueError, match=rf"^image file {tmp_path} is a directory"):
        load_image(str(tmp_path))


# ------------------------------------------------------------------------------------------------ warp
@pytest.mark.parametrize("far", [1e20, 1e100, -1e25])
def test_a_vertex_far_outside_the_picture_still_draws_its_triangle(far):
    """Beyond 9.2e18 pixels the int64 cast overflowed and the triangle drew nothing."""
    F = np.array([[0, 1, 2]])
    X = np.array([[2.0, 2.0], [8.0, 2.0], [2.0, far]])
    face, bary = warp.rasterize(X, F, (10, 10))
    inside = face >= 0
    # the picture's part of the triangle: columns 2..7 (up to rounding at x = 8) of rows 2.. (far > 0) or ..2
    if far > 0:
        assert inside[2:, 2:8].all() and not inside[:2].any() and not inside[:, :2].any()
    else:
        assert inside[:3, 2:8].all() and not inside[3:].any() and not inside[:, :2].any()
    np.testing.assert_allclose(bary[inside].sum(axis=1), 1.0)


@pytest.mark.parametrize(
    "mask, match",
    [
        (np.zeros((5, 5), bool), r"^mask has no True pixel"),
        (
            np.ones((5, 5, 3), bool),
            r"^mask must be an \(H, W\) array of booleans, got shape \(5, 5, 3\); for a picture",
        ),
        (np.full((4, 4), 0.5), r"^mask must be an \(H, W\) array of booleans \(or 0/1\)"),
        ("mask", r"^mask must be an \(H, W\) array of booleans, got shape \(\)"),
    ],
)
def test_image_to_mesh_frame_names_a_bad_mask(mask, match):
    """An all-False mask raised numpy's 'zero-size array to reduction operation'; (H, W, 3) a wrong frame."""
    with pytest.raises(ValueError, match=match):
        warp.image_to_mesh_frame(mask)


# ------------------------------------------------------------------------------------------------ configuration
@pytest.mark.parametrize("value", ["~nosuchuser_defop", "{file}/sub", "{file}"])
def test_a_cache_directory_that_cannot_be_made_says_how_to_fix_it(tmp_path, monkeypatch, value):
    """DEFOP_CACHE=~nosuchuser raised pathlib's RuntimeError('Could not determine home directory.')."""
    file = tmp_path / "a_file"
    file.write_text("x")
    monkeypatch.setenv("DEFOP_CACHE", value.format(file=file))
    with pytest.raises(ValueError, match=r"^DEFOP_CACHE=.*set DEFOP_CACHE to a writable directory, or DEFOP_CACHE=off"):
        config.cache_dir()


# ------------------------------------------------------------------------------------------------ mesh files
@pytest.fixture(scope="module")
def npz(bar, tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "bar.npz"
    write_mesh(path, bar.mesh)
    return path.read_bytes()


def _npz_with(members, compression=zipfile.ZIP_DEFLATED):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _npy_header(shape, descr="<f8"):
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def test_mesh_files_round_trip_atomically(bar, tmp_path):
    for ext in ("npz", "obj", "off"):
        path = tmp_path / f"m.{ext}"
        write_mesh(path, bar.mesh)
        back = read_mesh(path)
        np.testing.assert_allclose(back.V, bar.mesh.V, atol=1e-15)
        np.testing.assert_array_equal(back.F, bar.mesh.F)
    assert sorted(os.listdir(tmp_path)) == ["m.npz", "m.obj", "m.off"]  # no temporary file is left


def test_a_failed_mesh_write_leaves_the_old_file(bar, tmp_path, monkeypatch):
    path = tmp_path / "m.npz"
    path.write_bytes(b"old")

    def fail(*a):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="No space left on device") as info:
        write_mesh(path, bar.mesh)
    assert info.value.filename == str(path) and path.read_bytes() == b"old" and os.listdir(tmp_path) == ["m.npz"]
    with pytest.raises(ValueError, match=r"^mesh must be a defop Mesh, got ndarray"):
        write_mesh(tmp_path / "x.npz", bar.mesh.V)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda good: good[: len(good) // 2], r"is not an \.npz archive"),
        (lambda good: _npy_bytes(), r"is not an \.npz archive"),
        (
            lambda good: _npz_with(
                {"V.npy": _npy_header((10**9, 2)) + b"\0" * 10**6, "F.npy": _npy_header((1, 3), "<i8")}
            ),
            r"declares 1,000,000,000 rows of V, limit 10,000,000",
        ),
        (
            lambda good: _npz_with({"V.npy": b"\x93NUMPY\x01\x00" + b"{" * 5000, "F.npy": b""}),
            r"member V is not a numpy",
        ),
        (
            lambda good: _npz_with({"V.npy": _npy_header((2, 2), "|O") + b"\0" * 64, "F.npy": b""}),
            r"V must hold numbers, got dtype object",
        ),
        (lambda good: _npz_with({"V.npy": _npy_header((4, 2)) + b"\0" * 10, "F.npy": b""}), r"V is truncated"),
        (lambda good: _npz_with({"X.npy": b""}), r"holds no mesh \(arrays V and F are missing\)"),
        (lambda good: _npz_with({"V.npy": _raw_header("(" * 3000), "F.npy": b""}), r"member V is not a numpy array"),
        (lambda good: _npz_with({"V.npy": _raw_header("[" * 3000), "F.npy": b""}), r"member V is not a numpy array"),
        (
            lambda good: _npz_with({"V.npy": _raw_header("(" * 2400 + ")" * 2400), "F.npy": b""}),
            r"member V is not a numpy array",
        ),
    ],
)
def test_corrupt_npz_mesh_files_name_the_file(tmp_path, npz, make, match):
    path = tmp_path / "m.npz"
    path.write_bytes(make(npz))
    with pytest.raises(ValueError, match=rf"^mesh file {path}.*{match}"):
        read_mesh(path)


def _raw_header(shape_text):
    """An npy v1 header whose shape is ``shape_text`` (unbalanced or deeply nested: tokenize's TokenError before)."""
    hdr = ("{'descr': '<f8', 'fortran_order': False, 'shape': " + shape_text + "}").encode()
    hdr += b" " * (-(len(hdr) + 11) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(hdr).to_bytes(2, "little") + hdr


def _npy_bytes():
    buf = io.BytesIO()
    np.save(buf, np.zeros((3, 2)))
    return buf.getvalue()


def test_a_zip_bomb_stops_at_its_declared_size(tmp_path):
    """The member declares 4 vertices; its stream inflates to 100 MB of zeros: only the declared bytes are read."""
    V = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    members = {
        "V.npy": _npy_header(V.shape) + V.tobytes() + b"\0" * 10**8,
        "F.npy": _npy_header(F.shape, "<i8") + F.tobytes(),
    }
    path = tmp_path / "bomb.npz"
    path.write_bytes(_npz_with(members))
    assert path.stat().st_size < 10**6
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.V, V)


@pytest.mark.parametrize(
    "text, match",
    [
        ("OFF\n1000000000 1000000000 0\n0 0 0\n", r"declares 1,000,000,000 vertices and 1,000,000,000 faces"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n", r"could not be read as \.off"),
        ("not an off file\n", r"is not an OFF file"),
        ("OFF\nx y z\n", r"the OFF header has no vertex and face counts"),
    ],
)
def test_off_headers_are_checked_before_libigl_allocates(tmp_path, text, match):
    path = tmp_path / "m.off"
    path.write_text(text)
    with pytest.raises(ValueError, match=rf"^mesh file {path}:? {match}"):
        read_mesh(path)


def test_an_invalid_mesh_in_a_file_names_the_file(tmp_path):
    path = tmp_path / "flat.npz"
    with open(path, "wb") as fh:
        np.savez(fh, V=np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]), F=np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match=rf"^mesh file {path} holds an invalid mesh: 1 degenerate"):
        read_mesh(path)


def _damaged(data, good, head):
    """Random bytes, a truncation of ``good``, or ``good`` with up to 8 bytes among its first ``head`` changed."""
    how = data.draw(st.sampled_from(["random", "truncate", "mutate"]))
    if how == "random":
        return data.draw(st.binary(max_size=3000))
    if how == "truncate":
        return good[: data.draw(st.integers(0, len(good) - 1))]
    raw = bytearray(good)
    for _ in range(data.draw(st.integers(1, 8))):
        raw[data.draw(st.integers(0, min(len(raw), head) - 1))] = data.draw(st.integers(0, 255))
    return bytes(raw)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_damage_to_a_mesh_file_is_a_value_error_naming_it(npz, tmp_path_factory, data):
    """Random bytes, truncations and mutated bytes (headers included): a Mesh or a ValueError naming the file."""
    raw = _damaged(data, npz, head=len(npz))
    path = tmp_path_factory.mktemp("damaged") / data.draw(st.sampled_from(["m.npz", "m.off", "m.obj"]))
    path.write_bytes(raw)
    try:
        mesh = read_mesh(path)
    except ValueError as exc:
        assert str(path) in str(exc)
    else:
        assert mesh.n_vertices <= MAX_FILE_ELEMENTS and np.isfinite(mesh.V).all()


# ------------------------------------------------------------------------------------------------ compare
def test_score_all_refuses_per_method_lists_of_another_length(bar):
    """names or precompute shorter than methods silently dropped methods (zip); precompute=0 used the defaults."""
    from defop.analysis import compare

    peer = pe.make_peer(bar, "tps")
    Q = bar.P_moving[None] + [[[0.0, 0.05]]]
    X = peer(Q)
    scores, _ = compare.score_all([peer, peer], bar, Q, X, names=["a", "b"], precompute=[1.0, None])
    assert [s.name for s in scores] == ["a", "b"] and scores[0].precompute == 1.0
    for kw, match in [
        ({"names": ["a"]}, r"^names must be None or a list of one entry per method \(2\), got 1"),
        ({"precompute": 0}, r"^precompute must be None or a list .* got 0"),
        ({"precompute": [-1.0, None]}, r"^precompute must be None or seconds, .* got -1.0"),
    ]:
        with pytest.raises(ValueError, match=match):
            compare.score_all([peer, peer], bar, Q, X, **kw)
    with pytest.raises(ValueError, match=r"^Q must be a batch of shape \(k, 1, 2\)"):
        compare.score(peer, bar, 0.5, X)


@pytest.mark.parametrize("its", [(), 10, "10", (0,), (10, -1)])
def test_make_peers_needs_arap_iteration_counts(bar, its):
    """() silently made no ARAP peer; 10 raised 'int object is not iterable'."""
    with pytest.raises(ValueError, match=r"^arap_iterations must be "):
        pe.make_peers(bar, kinds=("tps", "arap"), arap_iterations=its)


@pytest.fixture(scope="module")
def pictures():
    """One small picture in each format Pillow writes without extra libraries."""
    rgb = (np.arange(24 * 32 * 3).reshape(24, 32, 3) % 253).astype(np.uint8)
    out = {}
    for fmt, ext in (("PNG", "png"), ("JPEG", "jpg"), ("BMP", "bmp"), ("GIF", "gif"), ("TIFF", "tif")):
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format=fmt)
        out[ext] = buf.getvalue()
    return out


@pytest.mark.filterwarnings(
    "ignore:Tag data larger than file:UserWarning", "ignore:Corrupt EXIF data:UserWarning", "ignore::UserWarning:PIL"
)
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_damage_to_an_image_file_is_a_value_error_naming_it(pictures, tmp_path_factory, data):
    """Random bytes, truncations and mutated bytes (headers first): pixels in [0, 1] or a ValueError naming the file."""
    ext = data.draw(st.sampled_from(sorted(pictures)))
    raw = _damaged(data, pictures[ext], head=200)
    path = tmp_path_factory.mktemp("damaged") / f"p.{ext}"
    path.write_bytes(raw)
    try:
        img = load_image(path)
    except ValueError as exc:
        assert str(path) in str(exc)
    else:
        assert np.isfinite(img).all() and img.min() >= 0 and img.max() <= 1

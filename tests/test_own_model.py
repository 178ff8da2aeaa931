"""Your own model to a page in one command: ``python -m defop page INPUT`` (:func:`defop.own_model`).

- Generated inputs of every kind (an outline as CSV and as SVG with a curved path, a picture written as PNG, a
  closed torus written by PyVista as STL and as OBJ) go through the command in fast mode: it prints its plan with
  an estimate, trains, writes the page and a PNG; each page opens in headless Chromium (the machinery of
  tests/test_browser_editor.py), a handle is dragged with the mouse, and the dragged handles' vertices land on their
  targets within 1e-12 of the diagonal.
- The automatic handles follow one rule in 2D and 3D: a star's tips, a patch per extremity in 3D, handle 0 fixed.
- Bad input (a missing file, an unknown ending, an empty, crossing or too short polygon, a CSV row that is not two
  numbers, a fixed handle out of range, a handle outside the shape) is a clear error naming it, and nothing is
  written; ``--dry-run`` says what it would train and how long it takes, and writes nothing.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_browser_editor import chromium_page, mouse_drag  # tests/ is on sys.path (rootdir conftest)

import defop as dop
from defop.__main__ import main
from defop.editor import model_page

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", autouse=True)
def fast(tmp_path_factory):
    """Fast mode and a cache of this module's own."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DEFOP_FAST", "1")
        mp.setenv("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


def star(k=5, inner=0.45):
    """A k-pointed star outline (2k vertices), tips at radius 1, the first on +x."""
    t = np.linspace(0, 2 * np.pi, 2 * k, endpoint=False)
    r = np.where(np.arange(2 * k) % 2 == 0, 1.0, inner)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """One generated file of every kind: CSV and SVG outlines, a PNG picture, a torus as STL and OBJ."""
    import matplotlib.pyplot as plt
    import pyvista as pv

    d = tmp_path_factory.mktemp("inputs")
    P = star()
    (d / "star.csv").write_text("x,y\n" + "\n".join(f"{x!r},{y!r}" for x, y in P.tolist()) + "\n")
    # a rounded shape with one curved (cubic) side and a transform, as drawing programs write it
    path = "M 10 10 L 90 10 C 120 40 120 70 90 90 L 10 90 Z"
    (d / "blob.svg").write_text(
        '<svg xmlns="http://www.w3.org/2000/svg" width="200" height="120">'
        f'<g transform="translate(5,5)"><path d="{path}"/></g></svg>'
    )
    yy, xx = np.mgrid[:120, :160]
    mask = ((xx - 80) / 60) ** 2 + ((yy - 60) / 35) ** 2 < 1
    plt.imsave(d / "ellipse.png", np.where(mask, 0.1, 1.0), cmap="gray", vmin=0, vmax=1)
    torus = pv.ParametricTorus(ringradius=1, crosssectionradius=0.35, u_res=20, v_res=10, w_res=10)
    torus = torus.triangulate().clean()
    torus.save(d / "torus.stl")
    F = torus.faces.reshape(-1, 4)[:, 1:]
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(torus.points, float).tolist()]
    (d / "torus.obj").write_text("\n".join(lines + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]) + "\n")
    return d


def _drag_2d(page):
    """Drag moving handle 0 of the 2D page; (Q, X, where the pointer was released)."""
    end = mouse_drag(page, "window.defopEditor", 30, -25)
    state = page.evaluate("() => ({Q: Array.from(window.defopEditor.st.Q), X: Array.from(window.defopEditor.st.X)})")
    return np.array(state["Q"]).reshape(-1, 2), np.array(state["X"]).reshape(-1, 2), end


def _drag_3d(page):
    """Drag moving handle 0 of the 3D page by (40, -30) pixels in the view plane; (Q, X, Q before)."""
    e = "window.defopEditor"
    box = page.locator("canvas.defop-canvas").bounding_box()
    u, v = page.evaluate(f"() => {e}.handleScreen(0)")
    before = np.array(page.evaluate(f"() => Array.from({e}.st.Q)")).reshape(-1, 3)
    page.mouse.move(box["x"] + u, box["y"] + v)
    page.mouse.down()
    for t in np.linspace(0.2, 1.0, 5):
        page.mouse.move(box["x"] + u + 40 * t, box["y"] + v - 30 * t)
        page.wait_for_timeout(30)
    page.mouse.up()
    state = page.evaluate(f"() => ({{Q: Array.from({e}.st.Q), X: Array.from({e}.st.X)}})")
    return np.array(state["Q"]).reshape(-1, 3), np.array(state["X"]).reshape(-1, 3), before


def _check_page_drags(result):
    """Open the page in Chromium, drag a handle: it moves, and every moving handle's vertex is on its target."""
    op = result.op
    diag = op.mesh.bbox_diagonal
    with chromium_page() as page:
        page.goto(result.page.resolve().as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        if op.d == 2:
            Q, X, end = _drag_2d(page)
            np.testing.assert_allclose(Q[0], end, atol=1e-9 * diag)  # where the pointer was released
            rows = op.handles[op.moving]
        else:
            rest = np.array(page.evaluate("() => Array.from(window.defopEditor.st.X)")).reshape(-1, 3)
            # the 3D page keeps only the vertices it draws, renumbered: find each moving handle's row by its rest
            # position, which the page reproduces exactly (8b)
            rows = np.array([np.flatnonzero((rest == op.mesh.V[h]).all(axis=1))[0] for h in op.handles[op.moving]])
            Q, X, before = _drag_3d(page)
            assert np.linalg.norm(Q[0] - before[0]) > 0.01 * diag, "the handle did not move"
        errors, requests = page.errors, page.requests
    assert not errors, errors
    assert all(url.startswith(("file:", "data:", "about:")) for url in requests), requests
    assert np.linalg.norm(Q[0] - result.shape.P_moving[0]) > 0.01 * diag
    assert np.all(np.abs(X[rows] - Q) <= 1e-12 * diag), "the dragged handles are not exactly on target"


@pytest.mark.browser
@pytest.mark.parametrize("name", ["star.csv", "blob.svg", "ellipse.png", "torus.stl", "torus.obj"])
def test_the_command_makes_a_page_that_drags(inputs, tmp_path, capsys, monkeypatch, name):
    made = []  # what the command's own_model returned, to check the page against its operator
    real = model_page.own_model
    monkeypatch.setattr(model_page, "own_model", lambda *a, **kw: made.append(real(*a, **kw)) or made[-1])
    out = tmp_path / "page.html"
    assert main(["page", str(inputs / name), "-o", str(out), "--fast"]) == 0
    printed = capsys.readouterr().out
    assert "estimate: about" in printed and "wrote the page" in printed and "handle 0: fixed" in printed
    (result,) = made
    assert result.page == out and result.png == out.with_suffix(".png")
    from PIL import Image

    with Image.open(result.png) as im:
        assert im.format == "PNG" and im.width > im.height  # the rest pose beside a deformed pose
    d = 3 if name.startswith("torus") else 2
    assert result.shape.mesh.dim == d and len(result.own.groups) == dop.scene.auto_handles.DEFAULT_COUNT[d]
    _check_page_drags(result)


def test_the_command_in_a_subprocess(inputs, tmp_path):
    """``python -m defop page`` as a user runs it: its plan, its ETA, the page and the picture, exit code 0."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run(
        [sys.executable, "-m", "defop", "page", str(inputs / "star.csv"), "--fast", "-o", "star.html"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert "until about" in res.stdout and "wrote the picture" in res.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["star.html", "star.png"]


def test_automatic_handles_one_rule_in_2d_and_3d(inputs):
    """A star's 5 tips in 2D (the rule picks extremities, not concave corners); 4-vertex patches in 3D."""
    s = dop.shapes.from_polygon(star(), n_vertices=300, n_auto_handles=5)
    tips = star()[::2]
    np.testing.assert_allclose(np.sort(s.P, axis=0), np.sort(tips, axis=0), atol=1e-12)
    own = dop.scene.own_input.load_model(inputs / "torus.stl", n_vertices=300)
    assert [len(g) for g in own.groups] == [4, 4, 4] and own.fixed == (0,)
    assert own.shape.n_moving == 8 and not own.shape.moving[:4].any()
    # the extremities of a torus lie on its outer equator, and far apart
    c = own.shape.P.reshape(3, 4, 3).mean(axis=1)
    assert np.all(np.hypot(c[:, 0], c[:, 1]) > 1.1)
    gaps = np.linalg.norm(c[:, None] - c[None], axis=-1)[np.triu_indices(3, 1)]
    assert gaps.min() > 1.5


def test_polygon_files_holes_curves_transforms(tmp_path):
    """A CSV's blank row starts a hole; an SVG's transform is applied, its curve sampled, its y axis turned up."""
    from defop.geometry.planar.polygon_files import CURVE_POINTS, read_polygon_file

    (tmp_path / "ring.csv").write_text(
        "# a square with a square hole\nx;y\n0 0\n4 0\n4 4\n0 4\n0 0\n\n1,1\n1,2\n2,2\n2,1\n"
    )
    outer, holes = read_polygon_file(tmp_path / "ring.csv")
    np.testing.assert_array_equal(outer, [[0, 0], [4, 0], [4, 4], [0, 4]])  # the closing repetition dropped
    np.testing.assert_array_equal(holes[0], [[1, 1], [1, 2], [2, 2], [2, 1]])
    svg = (
        '<svg xmlns="http://www.w3.org/2000/svg"><g transform="translate(10,20)">'
        '<path d="M 0 0 L 4 0 Q 6 2 4 4 L 0 4 Z"/><polygon points="1,1 2,1 2,2"/></g></svg>'
    )
    (tmp_path / "shape.svg").write_text(svg)
    outer, holes = read_polygon_file(tmp_path / "shape.svg")
    assert len(outer) == 3 + CURVE_POINTS and len(holes) == 1
    np.testing.assert_allclose(outer[:2], [[10, -20], [14, -20]])  # translated, y negated
    assert np.isclose(outer[:, 0].max(), 15.0, atol=0.02)  # the quadratic's apex at x = 4 + 1
    s = dop.shapes.from_polygon(outer, holes, n_vertices=200)
    assert len(s.mesh.boundary_loops()) == 2


@settings(max_examples=30, deadline=None)
@given(
    radii=st.lists(st.floats(0.2, 5.0), min_size=3, max_size=40),
    sep=st.sampled_from([",", ";", "\t", " ", ", "]),
    header=st.booleans(),
    closed=st.booleans(),
)
def test_csv_outlines_read_back_exactly(tmp_path_factory, radii, sep, header, closed):
    """Any star-shaped outline written as CSV (any separator, with or without a header or a closing row) reads back
    bit for bit."""
    from defop.geometry.planar.polygon_files import read_polygon_file

    t = np.linspace(0, 2 * np.pi, len(radii), endpoint=False)
    P = np.column_stack([np.cos(t), np.sin(t)]) * np.array(radii)[:, None]
    rows = [*P.tolist(), *(P[:1].tolist() if closed else [])]
    text = ("x,y\n" if header else "") + "\n".join(f"{x!r}{sep}{y!r}" for x, y in rows) + "\n"
    path = tmp_path_factory.mktemp("csv") / "outline.csv"
    path.write_text(text)
    outer, holes = read_polygon_file(path)
    np.testing.assert_array_equal(outer, P)
    assert holes == []


def test_dry_run_says_what_and_how_long_and_writes_nothing(inputs, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["page", str(inputs / "star.csv"), "--dry-run"]) == 0
    printed = capsys.readouterr().out
    for what in ("vertices", "handles (placed automatically): 4, 1 fixed", "m = 9 samples", "energy sarap"):
        assert what in printed, printed
    assert "estimate: about" in printed and "one solve took" in printed
    assert list(tmp_path.iterdir()) == []


def _write_bad_inputs(d):
    (d / "empty.csv").write_text("x,y\n")
    (d / "bowtie.csv").write_text("0,0\n1,1\n1,0\n0,1\n")
    (d / "two.csv").write_text("0,0\n1,0\n")
    (d / "words.csv").write_text("x,y\n0,0\n1,zero\n1,1\n")
    (d / "model.xyz").write_text("0 0\n")
    (d / "square.csv").write_text("0,0\n1,0\n1,1\n0,1\n")


#: case: (the command's arguments, own_model's keywords, the message)
BAD = {
    "missing": (["missing.csv"], {}, r"no such input file: .*missing\.csv"),
    "unknown ending": (["model.xyz"], {}, r"model\.xyz: unknown kind '\.xyz'; accepted: polygon \(\.csv, \.svg\)"),
    "empty polygon": (["empty.csv"], {}, r"empty\.csv: no outline in it"),
    "self-intersecting": (["bowtie.csv"], {}, r"bowtie\.csv: .*(cross|intersect)"),
    "too few points": (["two.csv"], {}, r"two\.csv: .*(3|three)"),
    "non-numeric": (["words.csv"], {}, r"words\.csv: line 3: '1,zero' is not two numbers"),
    "fixed out of range": (
        ["square.csv", "--fixed", "7"],
        {"fixed": 7},
        r"fixed handle 7 is out of range: the model has 4 handles",
    ),
    "all fixed": (
        ["square.csv", "--handles", "2", "--fixed", "0", "1"],
        {"handles": 2, "fixed": [0, 1]},
        r"every one of the 2 handles is fixed",
    ),
    "handle outside": (
        ["square.csv", "--handles", "0.5,0.5", "3,3"],
        {"handles": [[0.5, 0.5], [3, 3]]},
        r"square\.csv: handle .*outside",
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_a_clear_error_and_nothing_is_written(tmp_path, capsys, monkeypatch, case):
    args, kw, message = BAD[case]
    _write_bad_inputs(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = sorted(tmp_path.iterdir())
    assert main(["page", *args, "-o", "out.html"]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err), err
    with pytest.raises(ValueError, match=message):
        dop.own_model(args[0], out="out.html", echo=None, **kw)
    assert sorted(tmp_path.iterdir()) == before  # nothing written

"""A sweep of the public entry points with a table of bad inputs (issue 26).

No entry point may answer input it was handed with a raw IndexError, KeyError, AttributeError,
RecursionError, MemoryError, UnicodeEncodeError, zipfile.BadZipFile or pickle error: only a ValueError,
TypeError or OSError whose message names the argument (the table says which word must appear).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_hostile_editor import setup  # noqa: F401 - the shared fixture (the bar and its DefOps)

import defop as dop
from defop.analysis import peers as pe
from defop.editor import export
from defop.editor.state import EditorState
from defop.geometry.mesh import read_mesh, write_mesh
from defop.geometry.planar.outlines import load_image
from defop.view import warp

SQUARE = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
HOSTILE = [None, 0.5, -1, 0, np.nan, np.inf, 1e300, "x", b"x", 1j, [], [[]], {}, object(), True]


@pytest.fixture(scope="module")
def world(setup, tmp_path_factory):  # noqa: F811 - the fixture imported above
    shape, ops = setup
    op = ops["tps"]
    state = EditorState(shape, {"tps": op}, kinds=("tps",))
    img = np.zeros((30, 40))
    img[8:22, 8:32] = 1.0
    return {"shape": shape, "op": op, "state": state, "img": img, "tmp": tmp_path_factory.mktemp("files")}


def _entries(w):
    """(label, call(bad), the word the message must hold) per argument of each public entry point."""
    s, op, st = w["shape"], w["op"], w["state"]
    tmp = w["tmp"]
    return [
        ("shapes.load name", lambda v: dop.shapes.load(v), "shape"),
        ("shapes.load n_vertices", lambda v: dop.shapes.load("bar", n_vertices=v), "n_vertices"),
        ("from_polygon outer", lambda v: dop.shapes.from_polygon(v, handles=[[0.5, 0.5]]), "polygon|outer|vert"),
        ("from_polygon handles", lambda v: dop.shapes.from_polygon(SQUARE, handles=v, n_vertices=60), "handle"),
        (
            "from_polygon n_vertices",
            lambda v: dop.shapes.from_polygon(SQUARE, handles=[[0.5, 0.5]], n_vertices=v),
            "n_vertices",
        ),
        ("from_image image", lambda v: dop.shapes.from_image(v), "image"),
        ("from_image size", lambda v: dop.shapes.from_image(w["img"], size=v, n_vertices=60), "size"),
        ("from_image threshold", lambda v: dop.shapes.from_image(w["img"], threshold=v), "threshold"),
        (
            "from_image n_auto_handles",
            lambda v: dop.shapes.from_image(w["img"], n_auto_handles=v, n_vertices=60),
            "n_auto_handles",
        ),
        ("Shape.targets Q", lambda v: s.targets(v), "Q"),
        ("solve targets", lambda v: dop.solve(s.mesh, s.handles, v), "targets"),
        ("solve energy", lambda v: dop.solve(s.mesh, s.handles, s.P, energy=v), "energy"),
        ("train m", lambda v: dop.train(s, m=v, progress=False, n_jobs=1, cache=False), r"\bm\b"),
        ("train basis", lambda v: dop.train(s, basis=v, m=8, progress=False, n_jobs=1, cache=False), "basis"),
        ("train seed", lambda v: dop.train(s, m=8, seed=v, progress=False, n_jobs=1, cache=False), "seed"),
        ("train n_jobs", lambda v: dop.train(s, m=8, progress=False, n_jobs=v, cache=False), "n_jobs"),
        (
            "DefOp call Q",
            lambda v: _NON_NUMBER(v) if isinstance(v, (str, bytes, dict)) or type(v) is object else op(v),
            "Q",
        ),
        ("make_peer kind", lambda v: pe.make_peer(s, v), "peer"),
        ("make_peer iterations", lambda v: pe.make_peer(s, "arap", iterations=v), "iterations"),
        ("make_peer alpha", lambda v: pe.make_peer(s, "mls-rigid", alpha=v), "alpha"),
        ("peer call Q", lambda v: pe.make_peer(s, "tps")(v), "Q"),
        ("warp_image image", lambda v: warp.warp_image(v, s.mesh.V, s.mesh.V, s.mesh.F), "image"),
        ("warp_image X", lambda v: warp.warp_image(w["img"], s.mesh.V, v, s.mesh.F), "X"),
        (
            "warp_image shape",
            lambda v: warp.warp_image(w["img"], s.mesh.V, s.mesh.V, s.mesh.F, shape=v),
            "shape|height|width",
        ),
        ("image_to_mesh_frame mask", lambda v: warp.image_to_mesh_frame(v), "mask"),
        ("EditorState shape", lambda v: EditorState(v), "shape"),
        (
            "EditorState pick_radius",
            lambda v: EditorState(s, {"tps": op}, kinds=("tps",), pick_radius=v),
            "pick_radius",
        ),
        ("EditorState set_Q", lambda v: st.set_Q(v), "Q"),
        ("EditorState set_handle i", lambda v: st.set_handle(v, [0.5, 0.1]), "handle index"),
        ("EditorState set_handle q", lambda v: st.set_handle(0, v), r"\bq\b"),
        ("EditorState drag", lambda v: (st.press(*st.Q[0]), st.drag(v, 0.1)), r"\(x, y\)|Q"),
        ("EditorState set_basis", lambda v: st.set_basis(v), "basis"),
        ("EditorState set_ground_truth", lambda v: st.set_ground_truth(v), "enabled"),
        ("to_html title", lambda v: export.to_html(op, tmp / "p.html", title=v), "title"),
        ("to_html path", lambda v: export.to_html(op, v, title="t"), "path"),
        ("to_html op", lambda v: export.to_html(v, tmp / "p.html"), r"\bop\b"),
        ("to_html shape", lambda v: export.to_html(op, tmp / "p.html", shape=v), "shape"),
        ("outside_regions Q", lambda v: st.outside_regions(v), "Q"),
        ("read_mesh path", lambda v: read_mesh(v), "path|mesh file"),
        ("write_mesh mesh", lambda v: write_mesh(tmp / "m.npz", v), "mesh"),
        ("load_image image", lambda v: load_image(v), "image"),
    ]


FORBIDDEN = (IndexError, KeyError, AttributeError, RecursionError, MemoryError, UnicodeEncodeError)


def _forbidden(exc):
    import pickle
    import zipfile

    return isinstance(exc, (*FORBIDDEN, zipfile.BadZipFile, pickle.UnpicklingError)) or not isinstance(
        exc, (ValueError, TypeError, OSError)
    )


def _NON_NUMBER(v):
    """DefOp's Q as strings or objects: tested in test_defop_call_names_q_for_non_numbers."""
    raise ValueError("Q: not swept here")


def test_no_entry_point_raises_a_raw_error_on_bad_input(world, monkeypatch):
    import re

    monkeypatch.chdir(world["tmp"])  # a hostile path such as "x" is a file name: written here, not in the repo
    problems, accepted = [], []
    for label, call, word in _entries(world):
        for value in HOSTILE:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    call(value)
            except Exception as exc:  # noqa: BLE001 - what was raised is the subject of the test
                if _forbidden(exc) or isinstance(exc, UnicodeError):
                    problems.append(f"{label}({value!r}): raw {type(exc).__name__}: {exc}")
                elif not re.search(word, str(exc)):
                    problems.append(f"{label}({value!r}): {type(exc).__name__} not naming /{word}/: {exc}")
            else:
                accepted.append(f"{label}({value!r})")
    world["state"].reset()
    assert not problems, "\n".join(problems)
    # what was accepted is legitimate: a name, a default (None) or a real value in range
    assert sorted(accepted) == sorted(_ACCEPTED), "\n".join(sorted(accepted))


@pytest.mark.parametrize("Q", ["x", b"x", {}, object()])
def test_defop_call_names_q_for_non_numbers(world, Q):
    with pytest.raises(ValueError, match=r"\bQ\b"):
        world["op"](Q)


# what may be accepted: a default (None), a value in range, a name, a bool as 0/1 (numpy casts it to a number)
_ACCEPTED = [
    "EditorState drag(-1)",
    "EditorState drag(0)",
    "EditorState drag(0.5)",
    "EditorState drag(True)",
    "EditorState pick_radius(0.5)",
    "EditorState pick_radius(1e+300)",
    "EditorState set_ground_truth(0)",
    "EditorState set_ground_truth(True)",
    "EditorState set_handle i(0)",
    "from_image size(0.5)",
    "from_image threshold(0.5)",
    "from_image threshold(None)",
    "from_polygon handles(None)",  # automatic handles (defop.scene.auto_handles)
    "from_polygon n_vertices(None)",
    "make_peer alpha(0.5)",
    "shapes.load n_vertices(None)",
    "to_html path('x')",
    "to_html title('x')",
    "to_html title(None)",
    "to_html shape(None)",
    "outside_regions Q(None)",
    "train m(None)",
    "train n_jobs(-1)",
    "train n_jobs(None)",
    "train seed(0)",
    "warp_image shape(None)",
]

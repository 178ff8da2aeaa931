"""The page of a multi-valued operator (issue 29, item 2 and 4): ``to_html(BranchedOperator)``.

In Node (the page's own module, ``tests/js/eval_branched.mjs``): every branch's D_b matches ``op(Q)`` of that
branch; the page's ``follow`` along a seeded back-and-forth path across the jump picks the same branch at every
frame as :class:`defop.operator.branched.FollowSession` (the same hysteresis loop), and ``global`` the same as
``choose``. In Chromium: a mouse drag across the jump and back switches the branch label where the Python follow
does, with the handles exact. The bar of Fig. 10 with the fixtures of tests/test_branches.py.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_branches import bar, found  # noqa: F401  (fixtures)
from test_browser_editor import ROOT, chromium_page, needs_node, node_run

import defop as dop
from defop.analysis import branches as ab
from defop.editor import export, payload

DRIVER = ROOT / "tests" / "js" / "eval_branched.mjs"


def seeded_path(P, seed=0, steps=20):
    """The back-and-forth path of test_branches' hysteresis test, jittered (seeded) across the x column."""
    Qs = ab.line_path(P, 0, [-0.15, -0.3], [-0.15, 0.3], steps)
    jitter = np.random.default_rng(seed).uniform(-0.01, 0.01, Qs.shape)
    return Qs + jitter


def node_branched(bop, Qs, tmp_path):
    """The page's makeBranched in Node (tests/js/eval_branched.mjs) on Qs: per-branch X, follow, global, jumps."""
    return node_run(DRIVER, payload.branched_to_payload(bop), Qs, tmp_path)


def python_follow(bop, Qs):
    """The Python follow session from the rest branch (as the page's reset): labels (k,), jumps, X."""
    s = bop.session(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        labels, X = s.run(np.asarray(Qs))
    return labels, s.jumps, X


@needs_node
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_page_follow_matches_python_follow(bar, found, seed, tmp_path):  # noqa: F811
    bop = found[3]
    Qs = seeded_path(bar.P_moving, seed)
    out = node_branched(bop, Qs, tmp_path)
    diag = bar.mesh.bbox_diagonal
    for b in bop.branches:  # every branch's D_b in the page (float32 factors) against its op(Q)
        X_js = np.array(out["branches"][b.label]).reshape(len(Qs), -1, 2)
        assert np.abs(X_js - b.op(Qs)).max() < 1e-5 * diag
    labels, jumps, X = python_follow(bop, Qs)
    page = np.array([f["branch"] for f in out["follow"]])
    assert np.array_equal(page, labels), (page, labels)  # the same branch at every frame
    assert [tuple(j) for j in out["jumps"]] == jumps
    half = len(Qs) // 2
    frames = [j[0] for j in jumps]
    assert any(f <= half for f in frames) and any(f > half for f in frames), jumps  # out and back: a loop
    X_js = np.array([f["X"] for f in out["follow"]]).reshape(X.shape)
    assert np.abs(X_js - X).max() < 1e-5 * diag
    moving = bar.handles[bar.moving]
    assert np.abs(X_js[:, moving] - Qs).max() < 1e-12  # Prop. 2 in the page, on every frame
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.array_equal(np.array(out["global"]), bop.choose(Qs))


@needs_node
@pytest.mark.parametrize("seed", [0, 1])
def test_page_evaluates_the_certified_domain_like_python(seed, tmp_path):
    """Issue 37: the page's follow and global on an operator whose domains g_b were fitted from certified labels
    (its own TPS per branch, format 2) and whose box warns: the same branch as Python at every frame of a loop."""
    from test_branches_domains import certified

    shape, _, _, _, _, bop = certified()
    assert all(b.domain.own for b in bop.branches)
    Qs = seeded_path(shape.P_moving, seed, steps=40)
    Qs = np.concatenate([Qs, shape.P_moving + [[[0.5, 0.0]]]])  # and one frame outside the box
    out = node_branched(bop, Qs, tmp_path)
    labels, jumps, X = python_follow(bop, Qs)
    page = np.array([f["branch"] for f in out["follow"]])
    assert np.array_equal(page, labels), (page, labels)
    assert [tuple(j) for j in out["jumps"]] == jumps and len(jumps) >= 2
    X_js = np.array([f["X"] for f in out["follow"]]).reshape(X.shape)
    assert np.abs(X_js - X).max() < 1e-5 * shape.mesh.bbox_diagonal
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.array_equal(np.array(out["global"]), bop.choose(Qs))
        _, g, _ = bop.estimates(Qs)
    assert np.allclose(np.array(out["g"]), g, rtol=1e-9, atol=1e-12)  # g_b itself, every frame and branch
    assert out["outside"] == [False] * (len(Qs) - 1) + [True]  # the box, as Python's warning


def test_branched_page_bad_input(bar, found, tmp_path):  # noqa: F811
    bop = found[3]
    with pytest.raises(ValueError, match="op must be a trained DefOp or BranchedOperator"):
        export.to_html("bar", tmp_path / "x.html")
    with pytest.raises(ValueError, match="shape must be a 2D shape"):
        export.to_html(bop, tmp_path / "x.html", shape=dop.shapes.load("bar_3d"))
    with pytest.raises(ValueError, match="title"):
        export.to_html(bop, tmp_path / "x.html", title=3)
    assert not (tmp_path / "x.html").exists()  # nothing written
    path = export.to_html(bop, tmp_path / "x.html")
    assert "2 branches" in path.read_text() and "follow" in path.read_text()


def _drag_along(page, Qs):
    """Press on moving handle 0 and move the mouse through the data positions Qs[:, 0]; returns the page's log."""
    box = page.locator("canvas.defop-canvas").bounding_box()
    u, v = page.evaluate("() => window.defopEditor.handleScreen(0)")
    page.mouse.move(box["x"] + u, box["y"] + v)
    page.mouse.down()
    labels = []
    for q in Qs[:, 0]:
        su, sv = page.evaluate("([x, y]) => window.defopEditor.st.view.toScreen(x, y)", [float(q[0]), float(q[1])])
        n = page.evaluate("() => window.defopEditor.st.op.log.length")
        page.mouse.move(box["x"] + su, box["y"] + sv)
        page.wait_for_function(f"() => window.defopEditor.st.op.log.length > {n}", timeout=30_000)
        labels.append(page.evaluate("() => window.defopEditor.ui.branch.dataset.branch"))
    page.mouse.up()
    return labels


@pytest.mark.browser
def test_branched_page_drag_in_chromium(bar, found, tmp_path):  # noqa: F811
    bop = found[3]
    path = export.to_html(bop, tmp_path / "bar_branches.html", shape=bar)
    Qs = seeded_path(bar.P_moving, 0)
    approach = bar.P_moving + np.linspace(0, 1, 6)[1:, None, None] * (Qs[0] - bar.P_moving)  # from rest to the start
    with chromium_page() as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        first = page.evaluate("() => window.defopEditor.ui.branch.textContent")
        shown = _drag_along(page, np.concatenate([approach, Qs]))
        log = page.evaluate("() => window.defopEditor.st.op.log")
        X = np.array(page.evaluate("() => Array.from(window.defopEditor.st.X)")).reshape(-1, 2)
        toggled = page.evaluate(
            "() => { const e = window.defopEditor; e.ui.globalMode.click(); return e.ui.branch.textContent; }"
        )
        page.evaluate("() => window.defopEditor.ui.reset.click()")
        after_reset = page.evaluate("() => [window.defopEditor.ui.branch.textContent, window.defopEditor.st.op.mode]")
        errors = page.errors
    assert not errors, errors
    assert first.startswith("branch 0 (follow")
    Q_page = np.array([e["Q"] for e in log]).reshape(len(log), -1, 2)
    page_labels = np.array([e["branch"] for e in log])
    # the frames the page evaluated: the Python follow session over the same Q picks the same branch at each
    labels, jumps, X_py = python_follow(bop, Q_page)
    assert np.array_equal(page_labels, labels), (page_labels, labels)
    path_Q = np.concatenate([approach, Qs])
    assert len(log) == len(path_Q) + 2  # the load at P, one frame per pointer move, the release
    assert [int(s) for s in shown] == list(page_labels[1:-1])  # the label shown after every move
    # the pointer reached the path's positions (to the screen's pixels, about 1e-3 here)
    assert np.abs(Q_page[1:-1] - path_Q).max() < 2e-3
    # the label switches on the way out and on the way back, at the frames where the Python follow of the path
    # itself (no pixels) switches
    _, planned, _ = python_follow(bop, path_Q)
    half = len(approach) + len(Qs) // 2
    across = [j for j in planned if j[0] >= len(approach)]  # the back-and-forth path after the approach from P
    assert len(across) == 2 and across[0][0] <= half < across[1][0], planned
    assert [(f - 1, a, b) for f, a, b in jumps] == planned, (jumps, planned)
    moving = bar.handles[bar.moving]
    assert np.abs(X[moving] - Q_page[-1]).max() < 1e-12  # handles exact
    assert np.abs(X - X_py[-1]).max() < 1e-5 * bar.mesh.bbox_diagonal
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert toggled == f"branch {bop.choose(Q_page[-1])} (global)"  # the toggle: global's branch at this Q
    assert after_reset[0].startswith("branch 0")


REJECT = """(bad) => {
  const op = window.defopEditor.st.op;
  const snap = () => JSON.stringify([op.branch, op.frame, op.jumps, op.far, op.log.length, op.mode]);
  const num = { NaN: NaN, inf: Infinity, "-inf": -Infinity };
  const out = [];
  for (const Q of bad) {
    for (const call of ["step", "evaluate"]) {
      const before = snap();
      let error = "no error";
      try { op[call](Q.map((v) => (v in num ? num[v] : v))); } catch (e) { error = e.name + ": " + e.message; }
      out.push([call, error, before === snap()]);
    }
  }
  return out;
}"""


@pytest.mark.browser
def test_branched_page_rejected_frame_changes_nothing(bar, found, tmp_path):  # noqa: F811
    """Issue 35: the page's follow validates Q before any state changes (branch, frame, jumps, log, far)."""
    bop = found[3]
    path = export.to_html(bop, tmp_path / "bar_branches.html", shape=bar)
    Qs = seeded_path(bar.P_moving, 0)
    with chromium_page() as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        page.evaluate("() => window.defopEditor.st.op.reset()")
        half = len(Qs) // 2 + 3  # past the first jump: a state with a jump in it
        flat = [q.ravel().tolist() for q in Qs]
        page.evaluate("(Qs) => { for (const Q of Qs) window.defopEditor.st.op.evaluate(Q); }", flat[:half])
        mid = page.evaluate("() => { const o = window.defopEditor.st.op; return [o.branch, o.frame, o.jumps]; }")
        P = bar.P_moving.ravel().tolist()
        bad = [["NaN", P[1]], ["inf", P[1]], [P[0], "-inf"], [1e200, 1e200], [P[0]], [P[0], P[1], 0.0]]
        results = page.evaluate(REJECT, bad)
        rest = page.evaluate(
            "(Qs) => Qs.map((Q) => window.defopEditor.st.op.evaluate(Q) && window.defopEditor.st.op.branch)",
            flat[half:],
        )
        final = page.evaluate("() => { const o = window.defopEditor.st.op; return [o.frame, o.jumps]; }")
        errors = page.errors
    assert not errors, errors
    assert mid[1] == half and len(mid[2]) == 1, mid
    for call, error, unchanged in results:
        assert error.startswith("RangeError") and "Q" in error, (call, error)
        assert unchanged, (call, error)
    # the rejected frames left no trace: the rest of the path gives the Python follow's labels and jumps
    labels, jumps, _ = python_follow(bop, Qs)
    assert rest == labels[half:].tolist()
    assert final[0] == len(Qs) and [tuple(j) for j in final[1]] == jumps

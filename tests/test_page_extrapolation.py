"""One extrapolation rule in Python and in the page: :data:`defop.operator.core.EXTRAPOLATION_FACTOR` times the
farthest training sample of each moving handle, exported into the page's payload
(:func:`defop.editor.payload.extrapolation_payload`) and applied by ``extrapolating`` of
``defop/editor/static/defop_editor.js``, which the 2D editor and the 3D view (``defop_solid.js``) both call.

A handle dragged to 1.4x its reach (any direction) is flagged by neither the operator's ExtrapolationWarning, the
editor's state nor the page; at 1.6x by all three; in 2D (the U, discs) and 3D (the tet bar, balls).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_browser_editor import DRIVER, needs_node, node_run, operators, shape  # noqa: F401  (fixtures)
from test_page_3d import bar3, ops3  # noqa: F401  (fixtures)

import defop as dop
from defop.editor import payload
from defop.editor.state import EditorState
from defop.operator.core import EXTRAPOLATION_FACTOR
from defop.operator.defop import training_reach

FACTORS = (0.5, 1.0, 1.4, 1.6, 3.0)


def _drags(op, seed):
    """Each moving handle in turn moved to t x its reach (t in FACTORS) in a random direction, the others at rest:
    Qs (k,n,d) and the handles the rule flags."""
    rng = np.random.default_rng(seed)
    reach = training_reach(op.P, op.train_samples)
    Qs, flagged = [], []
    for j in range(op.n_moving):
        for t in FACTORS:
            u = rng.standard_normal(op.d)
            Q = op.P.copy()
            Q[j] += t * reach[j] * u / np.linalg.norm(u)
            Qs.append(Q)
            flagged.append([j] if t > EXTRAPOLATION_FACTOR else [])
    return np.array(Qs), flagged


def _python_flags(op, Qs):
    """The handles the operator's ExtrapolationWarning names, per Q."""
    out = []
    for Q in Qs:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            op(Q)
        said = [w for w in caught if issubclass(w.category, dop.operator.ExtrapolationWarning)]
        out.append([int(str(w.message).split()[2]) for w in said])  # "moving handle j is ..."
    return out


@needs_node
@pytest.mark.parametrize("dim", [2, 3])
def test_python_and_page_flag_the_same_drags(operators, ops3, dim, tmp_path):  # noqa: F811
    op = operators["tps"] if dim == 2 else ops3["tps"]
    Qs, expected = _drags(op, seed=dim)
    p = payload.defop_to_payload(op)
    assert p["extrapolation_factor"] == EXTRAPOLATION_FACTOR == 1.5
    np.testing.assert_array_equal(p["reach"], training_reach(op.P, op.train_samples))
    page = [o["outside"] for o in node_run(DRIVER, p, Qs, tmp_path)]
    python = _python_flags(op, Qs)
    assert page == python == expected
    assert any(expected) and not all(expected)


def test_editor_state_flags_the_same_drags(operators, shape):  # noqa: F811
    state = EditorState(shape, operators, basis="tps")
    Qs, expected = _drags(state.operator, seed=5)
    assert [state.outside_regions(Q) for Q in Qs] == expected


def test_both_pages_use_the_exported_rule():
    """Neither script holds a factor of its own: both call ``extrapolating`` with the payload's."""
    editor = payload.JS_PATH.read_text()
    solid = payload.JS_PATH.with_name("defop_solid.js").read_text()
    assert "p.extrapolation_factor * p.reach[i]" in editor
    assert "st.outside = extrapolating(st.Q, st.p);" in editor
    assert "st.outside = extrapolating(st.Q, p);" in solid
    assert "outsideRegions(" not in editor.split("export function outsideRegions", 1)[1].split("\n", 1)[1]
    assert "outsideRegions" not in solid

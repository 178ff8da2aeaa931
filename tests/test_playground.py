"""The playground (notebook 11): every shape of the in-page editor's menu trains, and the notebook never hangs."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop import figures
from defop.editor.browser import BrowserEditor
from defop.editor.state import EditorState


def test_every_shape_in_the_menu_trains_with_enough_samples(tmp_path, monkeypatch):
    """Each shape trains (empty cache) with at least the fewest samples its moving handles need (m=1 asks
    for fewer), as the page's shape menu does; a drag then interpolates the handle (Prop. 2)."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    monkeypatch.setenv("DEFOP_N_JOBS", "1")
    names = dop.shapes.names()
    editor = BrowserEditor("bar", shapes=names, m=1)
    assert editor.payload_meta["scalars"]["shapes"] == list(names)
    for name in names:
        editor.shape_name = name  # the page's shape menu
        s = editor.state
        assert s.shape.name == name and editor.payload_meta["scalars"]["n_vertices"] == s.mesh.n_vertices
        need = dop.training.min_samples("tps", s.shape.n_moving)
        assert len(s.operator.handle_basis.centers) >= need + 1  # the samples and the rest pose
        q = s.Q[0] + 0.05 * s.diag
        editor.q = np.vstack([q, s.Q[1:]]).ravel().tolist()  # a release in the page
        np.testing.assert_allclose(s.X[s.shape.moving_handles[0]], q, atol=1e-9 * s.diag)


@pytest.mark.parametrize("kind", dop.operator.handle_bases.KINDS)
def test_min_samples_is_the_fewest_the_fit_accepts(kind):
    """Checked against problem (8) itself: the fit takes min_samples samples and rejects one fewer."""
    shape = dop.shapes.load("u_shape")
    need = dop.training.min_samples(kind, shape.n_moving)
    rng = np.random.default_rng(1)
    samples = dop.training.sampling.sample_shape(shape, need, rng)
    X = shape.mesh.V + 0.01 * rng.standard_normal((need, *shape.mesh.V.shape))
    args = (shape.mesh, shape.handles, shape.moving)
    dop.operator.fit.fit(*args, samples, X, kind, "hat")
    with pytest.raises(ValueError, match="needs at least"):
        dop.operator.fit.fit(*args, samples[1:], X[1:], kind, "hat")


def test_a_basis_switch_trains_with_its_own_minimum(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    state = EditorState("u_shape", m=1)
    state.set_basis("quadratic")
    assert state.operator.handle_basis.size == dop.operator.handle_bases.basis_size("quadratic", 2)


def test_the_stored_output_is_a_picture_and_a_line(tmp_path, monkeypatch):
    """What a stored notebook keeps of the editor (figures.normalise drops the widget view)."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    editor = BrowserEditor("u_shape", m=5)
    bundle = editor._repr_mimebundle_()
    assert figures.WIDGET_VIEW in bundle
    out = figures.storing._static_outputs([{"output_type": "display_data", "data": dict(bundle), "metadata": {}}])
    assert set(out[0]["data"]) == {"image/png", "text/plain"}
    assert out[0]["data"]["text/plain"].startswith("Handle editor: u_shape")


@pytest.mark.slow
def test_playground_runs_20_times_in_a_row_through_the_main_job_without_hanging():
    """ipykernel 7 under nbclient hung on this notebook in 3 of 22 runs; a hang now fails after 120 s."""
    lines = []
    for _ in range(20):
        (run,) = figures.regenerate(
            only="11_playground", fast=True, store=False, timeout=120, log=lines.append, record=None
        )
        assert run["ok"], run["error"]
    assert sum("started" in ln for ln in lines) == 20

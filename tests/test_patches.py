"""Handle patches (a 3D handle is a patch of vertices) and their rigid sampling, the default of 3D training; the one
progress display over every stage of ``train``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.scene.handles import patches
from defop.training import sampling


@pytest.fixture(scope="module")
def bar3():
    return dop.shapes.load("bar_3d", n_vertices=300)


def _spread(Q, P):
    """Largest change of a distance between two handles of Q (m,k,3) from the rest P (k,3)."""
    d = lambda X: np.linalg.norm(X[..., :, None, :] - X[..., None, :, :], axis=-1)  # noqa: E731
    return float(np.abs(d(Q) - d(P)).max())


def test_patches_of_the_catalogue(bar3):
    p = patches(bar3)
    assert len(p) == 1 and p.rigid and list(p.members[0]) == [0, 1, 2, 3]
    np.testing.assert_array_equal(p.vertices[0], bar3.moving_handles)
    np.testing.assert_allclose(p.centres[0] + p.offsets, bar3.P_moving, atol=1e-15)
    assert p.radii[0] == 0.12 and np.array_equal(p.of(), [0, 0, 0, 0])
    octo = patches(dop.shapes.load("octopus_3d", n_vertices=1000))
    assert len(octo) == 9 and not octo.rigid
    flat = patches(dop.shapes.load("octopus"))  # 2D: every handle a point, a patch of its own
    assert not flat.rigid and len(flat) == dop.shapes.load("octopus").n_moving


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_rigid_patch_samples_are_rigid_motions_of_the_region_size(bar3, seed):
    p = patches(bar3)
    Q = sampling.rigid_patch_samples(p, 20, np.random.default_rng(seed), jitter=0)
    assert _spread(Q, bar3.P_moving) < 1e-12  # the patch keeps its shape
    assert (np.linalg.norm(Q.mean(axis=1) - p.centres[0], axis=1) <= 0.12 + 1e-12).all()  # translation in the ball
    off = Q - Q.mean(axis=1, keepdims=True)
    cosang = np.einsum("mka,ka->m", off, p.offsets) / (p.offsets**2).sum()  # cos of the turn about the normal ...
    assert (cosang >= np.cos(sampling.MAX_TURN) - 1e-9).all()  # ... never beyond 90 degrees


def test_3d_training_samples_move_the_patch_rigidly_by_default(bar3):
    """Before: each handle of the end face in its own ball of 0.12, the face torn by up to 0.2 (the face is 0.12)."""
    Q = sampling.sample_shape(bar3, 50, np.random.default_rng(0))
    jitter = 2 * sampling.PATCH_JITTER * 0.12
    assert _spread(Q, bar3.P_moving) <= jitter + 1e-12
    torn = sampling.sample_shape(bar3, 50, np.random.default_rng(0), sampling="per_handle")
    np.testing.assert_array_equal(torn, sampling.sample_handles(bar3.P_moving, bar3.regions, 50, 0))
    assert _spread(torn, bar3.P_moving) > 0.1
    with pytest.raises(ValueError, match="sampling"):
        sampling.sample_shape(bar3, 5, 0, sampling="rigidly")
    with pytest.raises(ValueError, match="sampling"):
        dop.train(bar3, sampling="per handle")


def test_2d_and_single_handle_samples_are_unchanged():
    for name, n in (("octopus", None), ("octopus_3d", 1000), ("nut", 800)):
        shape = dop.shapes.load(name, n_vertices=n)
        ref = sampling.sample_handles(shape.P_moving, shape.regions, 30, np.random.default_rng(4))
        for how in ("auto", "rigid"):
            np.testing.assert_array_equal(sampling.sample_shape(shape, 30, np.random.default_rng(4), how), ref)


def test_train_shows_one_progress_display_over_every_stage():
    """Before: three bars (bootstrap solves, sample solves, re-solves), none with the whole training's ETA."""
    bars = []

    class Bar:
        def __init__(self, total, desc):
            self.total, self.descs, self.count, self.closed = total, [desc], 0, 0
            bars.append(self)

        def update(self, n):
            self.count += n

        def set_description(self, desc):
            self.descs.append(desc)

        def close(self):
            self.closed += 1

    shape = dop.shapes.load("bar", n_vertices=150)
    dop.train(shape, m=12, rounds=2, cache=False, n_jobs=1, progress=lambda total, desc: Bar(total, desc))
    assert len(bars) == 1
    (bar,) = bars
    assert bar.total == bar.count == 24 and bar.closed == 1
    stages = [d.split(": ")[-1] for d in bar.descs[1:]]
    assert stages == ["bootstrap solves", "sample solves", "re-solves, round 2 of 2"]

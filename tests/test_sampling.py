"""Handle samples Q_k: every region kind, seeded, fixed handles untouched."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.training import sampling
from defop.training.sampling import sample_handles

P = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


@pytest.mark.parametrize(
    "region, check",
    [
        (
            {"kind": "disc", "radius": 0.3},
            lambda d, q: np.all(d <= 0.3) and np.mean(d < 0.3 / np.sqrt(2)) == pytest.approx(0.5, abs=0.05),
        ),
        ({"kind": "circle", "radius": 0.2}, lambda d, q: np.allclose(d, 0.2)),
        ({"kind": "gaussian", "sigma": 0.1}, lambda d, q: np.std(q[:, 0]) == pytest.approx(0.1, rel=0.1)),
        ({"kind": "voronoi", "radius": 2.0}, lambda d, q: np.all(np.linalg.norm(q - P[1], axis=1) >= d)),
    ],
)
def test_region_kinds(region, check):
    Q = sample_handles(P, [region] * 3, 2000, np.random.default_rng(0))
    assert Q.shape == (2000, 3, 2)
    d = np.linalg.norm(Q[:, 0] - P[0], axis=1)
    assert check(d, Q[:, 0] - P[0])


def test_voronoi_stays_in_the_cell_and_mixture_mixes():
    mix = {
        "kind": "mixture",
        "components": [{"kind": "circle", "radius": 0.1}, {"kind": "voronoi", "radius": 0.8}],
        "weights": [1, 3],
    }
    Q = sample_handles(P, [mix] * 3, 4000, np.random.default_rng(1))
    d = np.linalg.norm(Q[:, 0] - P[0], axis=1)
    on_circle = np.isclose(d, 0.1)
    assert on_circle.mean() == pytest.approx(0.25, abs=0.03)
    q = Q[~on_circle, 0]
    assert np.all(np.linalg.norm(q - P[0], axis=1) <= np.linalg.norm(q[:, None] - P[1:], axis=-1).min(axis=1))


def test_seeded_and_reproducible():
    s = dop.shapes.load("octopus", n_vertices=600)
    a = dop.training.sampling.sample_shape(s, 50, 7)
    b = dop.training.sampling.sample_shape(s, 50, np.random.default_rng(7))
    assert np.array_equal(a, b) and a.shape == (50, s.n_moving, 2)
    assert not np.array_equal(a, dop.training.sampling.sample_shape(s, 50, 8))


def test_bad_input():
    with pytest.raises(ValueError, match="2 regions for 3 moving handles"):
        sample_handles(P, [{"kind": "disc", "radius": 1}] * 2, 5, 0)
    with pytest.raises(ValueError, match="needs a positive 'radius'"):
        sample_handles(P, [{"kind": "disc", "radius": -1}] * 3, 5, 0)
    with pytest.raises(ValueError, match="m must be a positive integer"):
        sample_handles(P, [{"kind": "disc", "radius": 1}] * 3, 0, 0)


# ------------------------------------------------- regions as classes: the same Q_k as before the refactor
def _reference_sample(rng, region, c, m, P, index):
    """The string-dispatched sampler the classes replaced (kept here as the reference for the same seed)."""

    def disc(k, radius):
        r = radius * np.sqrt(rng.uniform(size=k))
        t = rng.uniform(0, 2 * np.pi, size=k)
        return np.column_stack([r * np.cos(t), r * np.sin(t)])

    kind = region["kind"]
    if kind == "disc":
        return c + disc(m, region["radius"])
    if kind == "ellipse":
        return c + disc(m, 1.0) * np.asarray(region["axes"], float)
    if kind == "circle":
        t = rng.uniform(0, 2 * np.pi, size=m)
        return c + region["radius"] * np.column_stack([np.cos(t), np.sin(t)])
    if kind == "gaussian":
        return c + rng.normal(scale=region["sigma"], size=(m, 2))
    if kind == "voronoi":
        others = np.delete(P, index, axis=0)
        out = np.empty((0, 2))
        while len(out) < m:
            cand = c + disc(max(2 * (m - len(out)), 16), region["radius"])
            d_own = np.sum((cand - c) ** 2, axis=1)
            d_other = np.min(np.sum((cand[:, None] - others[None]) ** 2, axis=-1), axis=1)
            out = np.vstack([out, cand[d_own <= d_other]])
        return out[:m]
    w = np.asarray(region["weights"], float)
    comp = rng.choice(len(w), size=m, p=w / w.sum())
    out = np.empty((m, 2))
    for j, sub in enumerate(region["components"]):
        sel = np.flatnonzero(comp == j)
        if len(sel):
            out[sel] = _reference_sample(rng, sub, c, len(sel), P, index)
    return out


REGIONS = [
    {"kind": "disc", "radius": 0.3},
    {"kind": "ellipse", "axes": [0.06, 0.3]},
    {"kind": "circle", "radius": 0.2},
    {"kind": "gaussian", "sigma": 0.1},
    {"kind": "voronoi", "radius": 0.8},
    {
        "kind": "mixture",
        "components": [{"kind": "disc", "radius": 0.18}, {"kind": "voronoi", "radius": 0.45}],
        "weights": [0.5, 0.5],
    },
]


@settings(max_examples=25, deadline=None)
@given(
    st.integers(0, 2**32 - 1), st.lists(st.integers(0, len(REGIONS) - 1), min_size=3, max_size=3), st.integers(1, 300)
)
def test_classes_draw_the_same_samples_as_the_dicts_did(seed, kinds, m):
    regions = [REGIONS[k] for k in kinds]
    Q = sample_handles(P, regions, m, seed)
    rng = np.random.default_rng(seed)
    ref = np.stack([_reference_sample(rng, r, P[i], m, P, i) for i, r in enumerate(regions)], axis=1)
    assert np.array_equal(Q, ref)  # bit for bit: cached ground truths keyed on Q_k stay valid


@pytest.mark.parametrize("spec", REGIONS)
def test_every_region_validates_samples_and_outlines_itself(spec):
    region = dop.scene.regions.as_region(spec)
    assert region.kind == spec["kind"] and region.to_dict()["kind"] == spec["kind"]
    assert dop.scene.regions.as_region(region.to_dict()) == region
    pts = region.sample(np.random.default_rng(0), P[0], 500, P, 0)
    outlines = region.outlines(P[0], P, 0)
    assert pts.shape == (500, 2) and outlines and all(len(o) >= 3 for o, _ in outlines)
    if spec["kind"] in ("disc", "ellipse", "voronoi"):  # every sample inside the drawn outline
        from matplotlib.path import Path

        assert Path(outlines[0][0]).contains_points(pts, radius=1e-9).mean() > 0.99


@pytest.mark.parametrize(
    "spec, match",
    [
        ({"kind": "disc"}, r"region \(disc\): disc needs a positive 'radius', got None"),
        ({"kind": "disc", "radius": np.nan}, "positive 'radius', got nan"),
        ({"kind": "gaussian", "sigma": 0}, "positive 'sigma', got 0"),
        ({"kind": "ellipse", "axes": [1, -1]}, "two positive 'axes'"),
        ({"kind": "mixture", "components": [{"kind": "disc", "radius": 1}], "weights": [-1]}, "non-negative weights"),
        ({"kind": "mixture", "components": [{"kind": "blob"}], "weights": [1]}, "component 0 has unknown kind 'blob'"),
        ({"kind": "disc", "radius": 1, "sigma": 2}, r"unknown parameter\(s\) \['sigma'\]"),
        ({"radius": 1}, "must be a Region or a dict with a 'kind'"),
    ],
)
def test_bad_regions_are_named(spec, match):
    with pytest.raises(ValueError, match=match):
        dop.scene.regions.as_region(spec)


def test_sample_handles_reads_d_from_P():
    P = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    Q = sample_handles(P, [{"kind": "ball", "radius": 0.2}, {"kind": "gaussian", "sigma": 0.1}], 30, 4)
    assert Q.shape == (30, 2, 3) and np.linalg.norm(Q[:, 0] - P[0], axis=1).max() <= 0.2
    # the same seed gives the same 2D samples for a disc and a ball (a ball in 2D is a disc)
    P2 = P[:, :2]
    a = sample_handles(P2, [{"kind": "disc", "radius": 0.2}] * 2, 10, 7)
    b = sample_handles(P2, [{"kind": "ball", "radius": 0.2}] * 2, 10, 7)
    assert np.array_equal(a, b)
    with pytest.raises(ValueError, match=r"P must have shape \(n, d\) with d = 2 or 3, got \(2, 4\)"):
        sample_handles(np.zeros((2, 4)), [{"kind": "ball", "radius": 1}] * 2, 3, 0)
    with pytest.raises(ValueError, match="a disc region is defined in 2D, not 3D"):
        sample_handles(P, [{"kind": "disc", "radius": 0.2}] * 2, 3, 0)


@given(
    st.floats(-3.0, 3.0),
    st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    st.integers(0, 2),
    st.integers(0, 2**16),
)
@settings(max_examples=25, deadline=None)
def test_patch_motions_are_rigid_with_the_given_twist_and_shift(angle, shift, axis, seed):
    P = np.random.default_rng(seed).uniform(-1, 1, size=(5, 3))
    Q = sampling.patch_motions(P, [angle], [shift], axis=axis)[0]
    c = P.mean(0)
    assert np.allclose(Q.mean(0), c + shift, atol=1e-12)  # the centroid moves by the shift
    D0, D1 = P[:, None] - P[None], Q[:, None] - Q[None]
    assert np.allclose(np.linalg.norm(D0, axis=-1), np.linalg.norm(D1, axis=-1), atol=1e-12)  # rigid
    assert np.allclose((Q - c - shift)[:, axis], (P - c)[:, axis], atol=1e-12)  # no motion along the axis
    i, j = [k for k in range(3) if k != axis]  # the turn about +axis is `angle` (right-hand rule)
    u, v = (P - c)[:, [i, j]], (Q - c - shift)[:, [i, j]]
    turn = np.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], (u * v).sum(1))
    big = np.linalg.norm(u, axis=1) > 1e-3
    assert np.allclose(np.angle(np.exp(1j * (turn[big] - angle))), 0.0, atol=1e-9)


def test_twist_bend_samples_stay_in_their_ranges_and_reject_bad_input():
    P = np.array([[1.0, 0.04, 0.04], [1.0, 0.16, 0.04], [1.0, 0.16, 0.16], [1.0, 0.04, 0.16]])
    rigid = sampling.twist_bend_samples(P, 1.0, 0.3, 200, np.random.default_rng(0), jitter=0.0)
    assert rigid.shape == (200, 4, 3)
    shift = rigid.mean(1) - P.mean(0)
    assert np.abs(shift[:, 0]).max() < 1e-12 and np.linalg.norm(shift, axis=1).max() <= 0.3
    assert np.linalg.matrix_rank((rigid - rigid.mean(0)).reshape(200, -1), tol=1e-9) == 4  # cos, sin, two shifts
    Q = sampling.twist_bend_samples(P, 1.0, 0.3, 200, np.random.default_rng(0), jitter=0.02)
    assert np.linalg.norm(Q - rigid, axis=-1).max() <= 0.02  # each handle within its ball around the rigid motion
    assert np.linalg.matrix_rank((Q - Q.mean(0)).reshape(200, -1)) == 12  # the jitter fills R^12
    with pytest.raises(ValueError, match="angle"):
        sampling.twist_bend_samples(P, 4.0, 0.3, 5, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"shifts \(k,3\)"):
        sampling.patch_motions(P, [0.1, 0.2], [[0, 0, 0]])


@pytest.mark.parametrize("axis", [3, -1, True, "x"])
def test_the_patch_axis_is_named_when_it_is_not_a_coordinate_axis(axis):
    P = np.eye(3)
    with pytest.raises(ValueError, match="axis must be 0, 1 or 2"):
        sampling.twist_bend_samples(P, 0.5, 0.1, 3, np.random.default_rng(0), axis=axis)
    with pytest.raises(ValueError, match="axis must be 0, 1 or 2"):
        sampling.patch_motions(P, [0.1], [[0.0, 0.0, 0.0]], axis=axis)


def test_the_3d_patch_sampling_is_the_lessons_old_one_and_the_old_path_warns():
    P = np.array([[1.0, 0.0, 0.0], [1.0, 0.2, 0.0], [1.0, 0.0, 0.2]])
    new = sampling.twist_bend_samples(P, 0.8, 0.2, 7, np.random.default_rng(3), axis=0)
    with pytest.warns(DeprecationWarning, match="defop.training.sampling.twist_bend_samples"):
        old = dop.analysis.figure_data.twist_bend_samples
    assert old is sampling.twist_bend_samples
    np.testing.assert_array_equal(old(P, 0.8, 0.2, 7, np.random.default_rng(3), axis=0), new)

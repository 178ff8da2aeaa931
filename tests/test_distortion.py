"""defop.analysis.distortion: the cusp, fold and scaling measures of Fig. 6 (analytic cases)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from defop.analysis import distortion
from defop.geometry.mesh import Mesh

RIGHT = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def _fan(n=6):
    """A regular fan of n triangles around vertex 0 (a one-ring), counter-clockwise."""
    a = 2 * np.pi * np.arange(n) / n
    V = np.vstack([[0.0, 0.0], np.column_stack([np.cos(a), np.sin(a)])])
    F = np.array([[0, 1 + k, 1 + (k + 1) % n] for k in range(n)])
    return Mesh(V, F)


def test_corner_angles_of_a_stretched_right_triangle():
    F = np.array([[0, 1, 2]])
    assert np.degrees(distortion.corner_angles(RIGHT, F))[0] == pytest.approx([90, 45, 45])
    X = RIGHT * [2.0, 1.0]  # J = diag(2, 1): angles 90, atan(1/2), atan(2)
    assert np.degrees(distortion.corner_angles(X, F))[0] == pytest.approx(
        [90, np.degrees(np.arctan(0.5)), np.degrees(np.arctan(2))]
    )
    folded = RIGHT * [1.0, -1.0]  # a reflection: every angle changes sign
    assert np.degrees(distortion.corner_angles(folded, F))[0] == pytest.approx([-90, -45, -45])


def test_handle_distortion_of_an_affine_stretch_and_a_fold():
    mesh = _fan()
    d = distortion.handle_distortion(mesh, mesh.V * [2.0, 1.0], [0])
    assert d["conformal"] == pytest.approx([2.0]) and d["flipped"].tolist() == [0]
    # the largest corner-angle change of diag(2, 1) over the fan's 60° corners, from the closed form
    ref = np.degrees(np.abs(distortion.corner_angles(mesh.V * [2.0, 1.0], mesh.F) - np.pi / 3)).max()
    assert d["angle"] == pytest.approx([ref]) and 10 < ref < 40
    X = mesh.V.copy()
    X[0] = [1.5, 0.0]  # the centre pulled out past the ring: a cusp that folds three triangles over
    d = distortion.handle_distortion(mesh, X, [0, 1])
    assert d["flipped"][0] >= 1 and d["conformal"][0] == np.inf and d["angle"][0] > 90


@settings(max_examples=30, deadline=None)
@given(st.floats(0, 2 * np.pi), st.floats(0.2, 5.0), st.floats(-3, 3), st.floats(-3, 3))
def test_similarities_have_no_distortion(angle, scale, tx, ty):
    mesh = _fan(7)
    c, s = np.cos(angle), np.sin(angle)
    X = scale * mesh.V @ np.array([[c, s], [-s, c]]) + [tx, ty]
    d = distortion.handle_distortion(mesh, X, [0, 3])
    assert np.allclose(d["angle"], 0, atol=1e-6) and np.allclose(d["conformal"], 1)
    summary = distortion.deformation_summary(mesh, X, [0], expand=1.1)
    assert summary["area_change"] == pytest.approx(scale**2 - 1)
    if abs(scale - 1.1) > 1e-6:
        assert summary["scaled"] == pytest.approx(1.0 if scale > 1.1 else 0.0)
    assert summary["median_conformal"] == pytest.approx(1.0) and summary["flips"] == 0


def test_wrong_shape_is_rejected():
    with pytest.raises(ValueError, match="X must have shape"):
        distortion.handle_distortion(_fan(), np.zeros((3, 2)), [0])

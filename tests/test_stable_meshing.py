"""Meshing a surface is stable under perturbations far below the mesh size (canonical coordinates).

Before the canonical grid, the surface was only rounded to float32: a copy perturbed by 1e-7 of the diagonal moved
the projections of the boundary vertices (and, through the thickness floor of ``snap_boundary``, whole moves),
so the tetrahedra and every cache entry keyed on them differed.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_surface_readers import _box_obj, _stl, torus

from defop.geometry.surface_files import bbox_diagonal
from defop.geometry.volumetric import surface as surf
from defop.scene.shapes import from_surface
from defop.training import cache

N_VERTICES = 400
HANDLES = np.array([[1.45, -0.2, 0.2], [1.15, -0.2, 0.2], [1.3, -0.2, -0.05]])


@functools.lru_cache(maxsize=1)
def _reference():
    V, F = torus(24, 12)
    Vc = surf.canonical_surface(V)
    return Vc, F, surf.surface_mesh(Vc, F, n_vertices=N_VERTICES)


def _grid(V):
    return math.ldexp(1.0, math.frexp(surf.SNAP_TOLERANCE * bbox_diagonal(V))[1] - 1)


def test_canonical_coordinates_are_on_the_stated_grid_and_idempotent():
    V, _ = torus(24, 12)
    Vc = surf.canonical_surface(V)
    g = _grid(Vc)
    assert surf.SNAP_TOLERANCE / 2 < g / bbox_diagonal(V) <= surf.SNAP_TOLERANCE
    assert np.array_equal(Vc / g, np.round(Vc / g)) and np.abs(Vc - V).max() <= g / 2 + 1e-7
    assert np.array_equal(surf.canonical_surface(Vc), Vc)


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), size=st.floats(0.01, 0.95))
def test_perturbations_below_the_tolerance_keep_the_mesh(seed, size):
    """A copy of a canonical surface, every coordinate moved by up to 1.9e-7 × the diagonal (times ``size``)."""
    Vc, F, ref = _reference()
    eps = size * 1.9e-7 * bbox_diagonal(Vc)
    W = Vc + np.random.default_rng(seed).uniform(-eps, eps, Vc.shape)
    assert (W != Vc).mean() > 0.9
    mesh = surf.surface_mesh(W, F, n_vertices=N_VERTICES)
    np.testing.assert_array_equal(mesh.V, ref.V)
    np.testing.assert_array_equal(mesh.F, ref.F)


def _key(shape):
    return cache.key("gt", shape.mesh.V, shape.mesh.F, shape.handles, shape.moving)


def test_the_stl_the_obj_and_a_perturbed_copy_share_the_mesh_and_the_cache_entry(tmp_path):
    Vc, F, ref = _reference()
    W = Vc + np.random.default_rng(5).uniform(-1.5e-7, 1.5e-7, Vc.shape) * bbox_diagonal(Vc)
    files = [_stl(tmp_path / "t.stl", Vc, F), _box_obj(tmp_path / "t.obj", Vc, F), _box_obj(tmp_path / "p.obj", W, F)]
    shapes = [from_surface(p, handles=HANDLES, n_vertices=N_VERTICES) for p in files]
    for s in shapes:
        np.testing.assert_array_equal(s.mesh.V, ref.V)
        np.testing.assert_array_equal(s.mesh.F, ref.F)
    assert len({_key(s) for s in shapes}) == 1

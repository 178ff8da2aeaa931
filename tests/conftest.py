"""Shared fixtures: small analytic meshes and reset of global plotting state (pyvista-examples style)."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

from hypothesis import settings  # noqa: E402

# CI and `make test` draw the same hypothesis examples on every run ("defop" profile, derandomized), so a
# result is reproducible and a red CI means a change, not a lucky draw. Explore new examples with
# HYPOTHESIS_PROFILE=explore make test; what it finds goes in as a regression test (tests/test_stranger_cases.py).
settings.register_profile("defop", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "defop"))

import defop as dop  # noqa: E402


@pytest.fixture(autouse=True)
def _reset_global_state():
    """Each test starts from default matplotlib rcParams and closes its figures."""
    import matplotlib

    yield
    import matplotlib.pyplot as plt

    plt.close("all")
    matplotlib.rcdefaults()


@pytest.fixture
def triangle():
    """One right triangle with legs 2 and 1 (area 1), counter-clockwise."""
    return dop.geometry.mesh.Mesh(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]]))


@pytest.fixture
def grid():
    """A structured 2 x 1 rectangle triangulated into 9 x 5 vertices."""
    x, y = np.meshgrid(np.linspace(0, 2, 9), np.linspace(0, 1, 5))
    V = np.column_stack([x.ravel(), y.ravel()])
    F = []
    for j in range(4):
        for i in range(8):
            a = j * 9 + i
            F += [[a, a + 1, a + 10], [a, a + 10, a + 9]]
    return dop.geometry.mesh.Mesh(V, np.array(F))


@pytest.fixture(scope="session")
def movable_rect():
    """A factory of the movable tests' 2 x 1 rectangle: ``movable_rect(n_vertices)`` -> a Shape named "rect" of
    about ``n_vertices`` vertices with two moving handles (at (1.8, 0.5) and (1.0, 0.8), discs of radius 0.15, the
    handles a placement region moves) and one fixed one (at (0.1, 0.5))."""

    def make(n_vertices):
        outer = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
        H = np.array([[1.8, 0.5], [1.0, 0.8], [0.1, 0.5]])
        return dop.shapes.from_polygon(
            outer,
            handles=H,
            moving=[True, True, False],
            n_vertices=n_vertices,
            name="rect",
            regions=[{"kind": "disc", "radius": 0.15}] * 2,
        )

    return make

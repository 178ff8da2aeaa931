"""Headless rendering: defop picks a working off-screen VTK window by itself, and images are not blank."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

import defop as dop


def test_render_mesh_offscreen_is_not_blank(grid, tmp_path):
    img = dop.view.render.render_mesh(
        grid,
        X=grid.V * [1.0, 1.5],
        handles=np.array([0, 44]),
        moving=np.array([True, False]),
        window_size=(200, 150),
        screenshot=tmp_path / "m.png",
    )
    assert img.shape == (150, 200, 3)
    white = np.all(img > 245, axis=-1)
    assert 0.05 < (~white).mean() < 0.95  # the mesh covers part of the image, not none and not all
    red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)
    assert red.sum() > 0  # the moving handle is drawn
    assert (tmp_path / "m.png").stat().st_size > 1000


def test_configure_headless_in_a_clean_process():
    """A fresh interpreter with no DISPLAY and no VTK setting renders through defop (no segfault)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")}
    code = (
        "import numpy as np, defop as dop, os\n"
        "m = dop.geometry.mesh.Mesh(np.array([[0,0],[1,0],[0,1.]]), np.array([[0,1,2]]))\n"
        "img = dop.view.render.render_mesh(m, window_size=(64,64))\n"
        "print(os.environ['VTK_DEFAULT_OPENGL_WINDOW'], int(img.std() > 0))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    window, nonblank = res.stdout.split()
    assert window in ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow") and nonblank == "1"


def test_no_window_gives_the_apt_line(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
    monkeypatch.setattr(dop.view.headless, "_chosen", None)
    monkeypatch.setattr(dop.view.headless, "candidates", lambda: [])
    if sys.platform in ("win32", "darwin"):
        pytest.skip("headless selection only applies to Linux")
    with pytest.raises(RuntimeError, match="apt-get install -y --no-install-recommends libosmesa6"):
        dop.view.render.configure_headless()


@pytest.fixture(scope="module")
def tets():
    from reference3d import box_tets  # tests/ is on sys.path (rootdir conftest)

    V, T = box_tets((4, 1, 1), (1.0, 0.25, 0.25))
    return dop.Mesh(V, T)


def test_a_tet_mesh_renders_its_boundary_surface(tets):
    poly = dop.view.render.to_polydata(tets.V, tets.F)
    assert poly.n_cells == len(tets.boundary_facets)  # the boundary triangles, not the tetrahedra's faces
    assert poly.volume == pytest.approx(tets.volumes.sum(), rel=1e-9)  # a closed surface around the solid
    img = dop.view.render.render_panels(tets, [tets.V, tets.V * [1, 2, 1]], ["rest", "stretched"], panel_size=(120, 90))
    assert img.shape == (90, 240, 3)
    white = np.all(img > 245, axis=-1)
    assert 0.02 < (~white[:, :120]).mean() < (~white[:, 120:]).mean() < 0.95  # the stretched bar covers more


@pytest.mark.parametrize("suffix", [".vtk", ".vtu", ".ply", ".stl"])
def test_deformed_meshes_are_written_and_read_back(tets, tmp_path, suffix):
    import pyvista as pv

    X = tets.V @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1.5]]).T + 0.25  # any map: written as given
    back = pv.read(dop.view.render.save_deformed(tmp_path / f"bar{suffix}", tets, X))
    if suffix in (".vtk", ".vtu"):
        assert back.n_cells == tets.n_faces and np.allclose(back.points, X, atol=1e-12)
    else:
        bv = tets.boundary_vertices
        assert back.n_cells == len(tets.boundary_facets) and back.n_points == len(bv)
        assert np.allclose(np.sort(np.asarray(back.points), 0), np.sort(X[bv], 0), atol=1e-5)  # float32 in STL
    with pytest.raises(ValueError, match="path must end in one of"):
        dop.view.render.save_deformed(tmp_path / "bar.xyz", tets, X)
    with pytest.raises(ValueError, match="X must be finite"):
        dop.view.render.save_deformed(tmp_path / f"bad{suffix}", tets, X[:, :2])
    assert not (tmp_path / f"bad{suffix}").exists()

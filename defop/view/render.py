"""PyVista rendering that works on a machine without a display.

VTK segfaults in ``supports_open_gl`` when there is no X display and no off-screen
window class is chosen (measured on Debian 12, VTK 9.7). :func:`configure_headless`
picks one by itself before the first ``Plotter`` is made:

1. ``vtkEGLRenderWindow`` when libEGL and a Mesa DRI driver are installed
   (Debian: ``libegl1 libgl1-mesa-dri``);
2. ``vtkOSOpenGLRenderWindow`` when OSMesa is installed (Debian: ``libosmesa6``).

Each candidate is probed in a child process (a crash there cannot take the caller down)
and the first that renders is exported through ``VTK_DEFAULT_OPENGL_WINDOW``, so that child
processes (Jupyter kernels started by nbclient) inherit it. A user's own setting of that
variable, or a ``DISPLAY``, is respected. The module configures itself on import.
"""

from __future__ import annotations

import ctypes.util
import glob
import os
import shutil
import subprocess
import sys

import numpy as np

#: Debian packages that provide each off-screen window class.
APT_PACKAGES = {
    "vtkEGLRenderWindow": ["libegl1", "libgl1-mesa-dri"],
    "vtkOSOpenGLRenderWindow": ["libosmesa6"],
}
APT_LINE = "apt-get install -y --no-install-recommends " + " ".join(APT_PACKAGES["vtkOSOpenGLRenderWindow"])

_DRI_GLOBS = (
    "/usr/lib/*/dri/swrast_dri.so",
    "/usr/lib/dri/swrast_dri.so",
    "/usr/lib64/dri/swrast_dri.so",
    "/usr/lib/*/dri/kms_swrast_dri.so",
)

_PROBE = """
import pyvista as pv
p = pv.Plotter(off_screen=True, window_size=(32, 32))
p.add_mesh(pv.Sphere(), color="red")
img = p.screenshot(return_img=True)
p.close()
assert img.std() > 0, "blank image"
print("ok")
"""

_chosen: str | None = None


def _has_egl() -> bool:
    return ctypes.util.find_library("EGL") is not None and any(glob.glob(g) for g in _DRI_GLOBS)


def _has_osmesa() -> bool:
    return ctypes.util.find_library("OSMesa") is not None


def candidates() -> list[str]:
    """Off-screen window classes whose system libraries are present, best first.

    Returns
    -------
    names : list of str
        A subset of ``["vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow"]``.
    """
    out = []
    if _has_egl():
        out.append("vtkEGLRenderWindow")
    if _has_osmesa():
        out.append("vtkOSOpenGLRenderWindow")
    return out


def probe(window: str, timeout: float = 60.0) -> bool:
    """Whether a Plotter with ``VTK_DEFAULT_OPENGL_WINDOW=window`` renders, tested in a child process.

    Parameters
    ----------
    window : str
        A VTK render-window class name.
    timeout : float
        Seconds before the child is considered hung.

    Returns
    -------
    ok : bool
    """
    env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW=window)
    env.pop("DISPLAY", None)
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False
    return res.returncode == 0 and "ok" in res.stdout


def configure_headless(force: bool = False) -> str | None:
    """Choose a working off-screen VTK window when there is no display.

    Parameters
    ----------
    force : bool
        Probe again even if a choice was made already in this process.

    Returns
    -------
    window : str or None
        The chosen class, ``None`` when a display exists (nothing to do).

    Raises
    ------
    RuntimeError
        When no candidate renders; the message gives the apt line that fixes it.
    """
    global _chosen
    if _chosen is not None and not force:
        return _chosen
    if os.environ.get("VTK_DEFAULT_OPENGL_WINDOW"):
        _chosen = os.environ["VTK_DEFAULT_OPENGL_WINDOW"]
        return _chosen
    if os.environ.get("DISPLAY") or sys.platform in ("win32", "darwin"):
        return None
    tried = []
    for window in candidates():
        tried.append(window)
        if probe(window):
            os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = window
            _chosen = window
            return window
    raise RuntimeError(
        "no off-screen OpenGL window works on this machine (no DISPLAY; tried "
        f"{tried or 'nothing: neither libEGL+Mesa DRI nor OSMesa is installed'}). "
        f"Install OSMesa with:  {APT_LINE}   (or run under xvfb-run -a)"
    )


def ensure_system_packages(install: bool = True) -> str:
    """Make headless rendering possible: install the missing Debian package when root, else explain.

    Used by ``python -m defop doctor`` (which ``make`` runs once after creating ``.venv``).

    Parameters
    ----------
    install : bool
        Run apt-get when no candidate exists and we are root on a Debian-like system.

    Returns
    -------
    message : str
        What was found or done.
    """
    if os.environ.get("DISPLAY"):
        return "DISPLAY is set: on-screen rendering"
    if candidates():
        return f"off-screen windows available: {', '.join(candidates())}"
    can_apt = shutil.which("apt-get") is not None and hasattr(os, "geteuid") and os.geteuid() == 0
    if install and can_apt:
        subprocess.run(["apt-get", "update", "-qq"], check=False)
        subprocess.run(APT_LINE.split(), check=True)
        if candidates():
            return f"installed {APT_PACKAGES['vtkOSOpenGLRenderWindow']}: {', '.join(candidates())}"
    return f"no off-screen OpenGL library found. Run as root:  {APT_LINE}"


def ensure_chromium(install=True):
    """Make sure Debian's chromium exists for the browser end-to-end test (apt-get as root).

    Parameters
    ----------
    install : bool

    Returns
    -------
    message : str
    """
    line = "apt-get install -y --no-install-recommends chromium"
    if shutil.which("chromium") or shutil.which("chromium-browser"):
        return f"chromium found at {shutil.which('chromium') or shutil.which('chromium-browser')}"
    can_apt = shutil.which("apt-get") is not None and hasattr(os, "geteuid") and os.geteuid() == 0
    if install and can_apt:
        subprocess.run(["apt-get", "update", "-qq"], check=False)
        res = subprocess.run(line.split(), check=False)
        if res.returncode == 0 and shutil.which("chromium"):
            return "installed chromium"
    return f"no chromium: the browser test will be skipped. Run as root:  {line}"


def _pyvista():
    configure_headless()
    import pyvista as pv

    return pv


def to_polydata(V, F, X=None, scalars=None):
    """A pyvista PolyData of a planar triangle mesh (z = 0).

    Parameters
    ----------
    V : (n,2) numpy array
        Rest vertex positions (used when ``X`` is None).
    F : (m,3) numpy array
        Triangles.
    X : (n,2) numpy array, optional
        Deformed positions.
    scalars : (n,) or (m,) numpy array, optional
        Point or cell data stored as ``"scalars"``.

    Returns
    -------
    poly : pyvista.PolyData
    """
    pv = _pyvista()
    P = np.asarray(V if X is None else X, dtype=float)
    pts = np.column_stack([P, np.zeros(len(P))])
    F = np.asarray(F, dtype=np.int64)
    faces = np.column_stack([np.full(len(F), 3), F]).ravel()
    poly = pv.PolyData(pts, faces)
    if scalars is not None:
        poly["scalars"] = np.asarray(scalars)
    return poly


def mesh_plotter(
    mesh,
    X=None,
    scalars=None,
    handles=None,
    moving=None,
    window_size=(800, 600),
    cmap="viridis",
    show_edges=True,
    off_screen=True,
    notebook=None,
):
    """A PyVista Plotter showing a (deformed) planar mesh, seen from above, with its handles.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        The rest mesh.
    X : (n,2) numpy array, optional
        Deformed vertex positions; the rest pose when None.
    scalars : (n,) or (m,) numpy array, optional
        Colours per vertex or per triangle.
    handles : (h,) int numpy array, optional
        Handle vertex indices, drawn as spheres.
    moving : (h,) bool numpy array, optional
        Which handles move (red); the others are fixed (blue).
    window_size : (2,) tuple
        Image size in pixels.
    cmap : str
        Colormap for ``scalars``.
    show_edges : bool
        Draw the triangle edges.
    off_screen, notebook : bool
        Passed to ``pyvista.Plotter``.

    Returns
    -------
    plotter : pyvista.Plotter
    """
    pv = _pyvista()
    P = mesh.V if X is None else np.asarray(X, dtype=float)
    poly = to_polydata(mesh.V, mesh.F, P, scalars)
    kw = {} if notebook is None else {"notebook": notebook}
    plotter = pv.Plotter(off_screen=off_screen, window_size=tuple(window_size), **kw)
    plotter.set_background("white")
    style = dict(show_edges=show_edges, edge_color="#555555", line_width=0.5)
    if scalars is None:
        plotter.add_mesh(poly, color="#f2d7a6", **style)
    else:
        plotter.add_mesh(poly, scalars="scalars", cmap=cmap, **style)
    if handles is not None and len(handles):
        handles = np.asarray(handles)
        moving = np.ones(len(handles), bool) if moving is None else np.asarray(moving, bool)
        radius = 0.012 * mesh.bbox_diagonal
        for idx, mv in zip(handles, moving, strict=True):
            c = np.append(P[idx], 0.0)
            plotter.add_mesh(pv.Sphere(radius=radius, center=c), color="#d62728" if mv else "#1f77b4")
    plotter.view_xy()
    plotter.enable_parallel_projection()
    plotter.reset_camera(bounds=poly.bounds)
    return plotter


def render_mesh(mesh, X=None, screenshot=None, **kw):
    """Render a (deformed) planar mesh off-screen with PyVista and return the image.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n,2) numpy array, optional
        Deformed positions.
    screenshot : str or path, optional
        Also write the image there (PNG).
    **kw
        As for :func:`mesh_plotter` (``scalars``, ``handles``, ``moving``, ``window_size``, ...).

    Returns
    -------
    img : (H,W,3) uint8 numpy array
    """
    plotter = mesh_plotter(mesh, X, off_screen=True, **kw)
    try:
        img = plotter.screenshot(filename=None if screenshot is None else str(screenshot), return_img=True)
    finally:
        plotter.close()
    return np.asarray(img)


def jupyter_backend():
    """The PyVista notebook backend: ``$PYVISTA_JUPYTER_BACKEND`` if set, else ``"trame"`` when the
    trame packages are installed and a display or a Jupyter server can show it, else ``"static"``
    (a PNG; what CI and headless runs use).

    Returns
    -------
    backend : str
    """
    env = os.environ.get("PYVISTA_JUPYTER_BACKEND")
    if env:
        return env
    try:
        import trame  # noqa: F401
        import trame_vtk  # noqa: F401
    except ImportError:
        return "static"
    return "static" if os.environ.get("DEFOP_FAST") or os.environ.get("CI") else "trame"


if __name__ != "__main__":
    # configure on import, but never raise here: the error surfaces on first use
    try:
        configure_headless()
    except RuntimeError:
        pass


def render_height_fields(xs, ys, fields, titles=None, window_size=(1200, 450), screenshot=None, cmap="coolwarm"):
    """PyVista height-field surfaces z = f(x, y) side by side (off-screen), e.g. trajectories (Fig. 3, 5).

    Parameters
    ----------
    xs : (nx,) numpy array
    ys : (ny,) numpy array
        Grid coordinates (handle displacements).
    fields : list of (ny,nx) numpy array
        One surface per subplot; all share one vertical scale.
    titles : list of str, optional
    window_size : (2,) tuple
    screenshot : path, optional
        Also write a PNG.
    cmap : str

    Returns
    -------
    img : (H,W,3) uint8 numpy array
    """
    pv = _pyvista()
    X, Y = np.meshgrid(xs, ys)
    span = max(np.ptp(xs), np.ptp(ys))
    zmax = max(float(np.abs(f).max()) for f in fields) or 1.0
    scale = 0.5 * span / zmax
    plotter = pv.Plotter(off_screen=True, shape=(1, len(fields)), window_size=tuple(window_size), border=False)
    try:
        for k, f in enumerate(fields):
            plotter.subplot(0, k)
            plotter.set_background("white")
            surf = pv.StructuredGrid(X, Y, np.asarray(f) * scale)
            surf["value"] = np.asarray(f).ravel(order="F")
            plotter.add_mesh(
                surf,
                scalars="value",
                cmap=cmap,
                clim=(-zmax, zmax),
                show_edges=True,
                edge_color="#333333",
                line_width=0.3,
                show_scalar_bar=False,
            )
            if titles:
                plotter.add_text(titles[k], font_size=10, color="black")
            plotter.camera_position = "iso"
            plotter.reset_camera(bounds=surf.bounds)
        img = plotter.screenshot(filename=None if screenshot is None else str(screenshot), return_img=True)
    finally:
        plotter.close()
    return np.asarray(img)

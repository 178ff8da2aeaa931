"""Off-screen rendering on a machine without a display: the choice of VTK window, and the system packages.

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

__all__ = [
    "APT_PACKAGES",
    "APT_LINE",
    "candidates",
    "probe",
    "configure_headless",
    "ensure_system_packages",
    "ensure_chromium",
    "jupyter_backend",
]

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

"""PyVista pictures of a (deformed) mesh, off-screen: one pose, panels of poses, height fields, and the standard
files (VTK, PLY, STL, OBJ) of a deformed mesh.

The off-screen window is chosen by :mod:`.headless` (imported here, it configures itself); its names are importable
from this module as well.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.mesh import boundary_facets
from . import headless
from .headless import *  # noqa: F403 (the names in headless.__all__)
from .headless import configure_headless

__all__ = [
    "FILL",
    "EXPORT_FORMATS",
    "to_polydata",
    "to_unstructured_grid",
    "save_deformed",
    "mesh_plotter",
    "render_mesh",
    "render_panels",
    "render_height_fields",
    *headless.__all__,
]

#: surface colour of a mesh without scalars
FILL = "#f2d7a6"


def _pyvista():
    configure_headless()
    import pyvista as pv

    return pv


def _surface_of(F):
    """Triangles to draw: F itself in 2D (triangles), the outward boundary surface of tetrahedra in 3D."""
    F = np.asarray(F, dtype=np.int64)
    if F.ndim != 2 or F.shape[1] not in (3, 4):
        raise ValueError(f"F must have shape (m,3) (triangles) or (m,4) (tetrahedra), got {F.shape}")
    return F if F.shape[1] == 3 else boundary_facets(F)


def to_polydata(V, F, X=None, scalars=None):
    """A pyvista PolyData of a triangle mesh (planar: z = 0) or of the boundary surface of a tetrahedral mesh.

    Parameters
    ----------
    V : (n,2) or (n,3) numpy array
        Rest vertex positions (used when ``X`` is None).
    F : (m,3) or (m,4) numpy array
        Triangles, or tetrahedra (the boundary triangles are drawn,
        :func:`defop.geometry.mesh.boundary_facets`).
    X : (n,2) or (n,3) numpy array, optional
        Deformed positions.
    scalars : (n,) numpy array, or (m,) for triangles, optional
        Point (or triangle) data stored as ``"scalars"``.

    Returns
    -------
    poly : pyvista.PolyData
    """
    pv = _pyvista()
    P = np.asarray(V if X is None else X, dtype=float)
    pts = P if P.shape[1] == 3 else np.column_stack([P, np.zeros(len(P))])
    T = _surface_of(F)
    faces = np.column_stack([np.full(len(T), 3), T]).ravel()
    poly = pv.PolyData(pts, faces)
    if scalars is not None:
        poly["scalars"] = np.asarray(scalars)
    return poly


def to_unstructured_grid(V, F, X=None):
    """A pyvista UnstructuredGrid of a tetrahedral mesh (every tetrahedron, for VTK files).

    Parameters
    ----------
    V : (n,3) numpy array
    F : (m,4) int numpy array
    X : (n,3) numpy array, optional
        Deformed positions.

    Returns
    -------
    grid : pyvista.UnstructuredGrid
    """
    pv = _pyvista()
    P = np.asarray(V if X is None else X, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    if P.ndim != 2 or P.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 4:
        raise ValueError(f"need V (n,3) and tetrahedra F (m,4), got {P.shape} and {F.shape}")
    cells = np.column_stack([np.full(len(F), 4), F]).ravel()
    return pv.UnstructuredGrid(cells, np.full(len(F), pv.CellType.TETRA, dtype=np.uint8), P)


#: file endings :func:`save_deformed` writes, and what goes in them
EXPORT_FORMATS = {".vtk": "volume", ".vtu": "volume", ".ply": "surface", ".stl": "surface", ".obj": "surface"}


def save_deformed(path, mesh, X=None, surface=None):
    """Write a (deformed) mesh to a standard file: the tetrahedra to VTK (``.vtk``, ``.vtu``), the boundary
    surface (or a fine embedded surface) to PLY, STL or OBJ. Triangle meshes (2D) are written at z = 0.

    Parameters
    ----------
    path : str or path
        Its ending picks the format (:data:`EXPORT_FORMATS`).
    mesh : defop.geometry.mesh.Mesh
    X : (n,d) numpy array, optional
        Deformed vertex positions; the rest pose when None.
    surface : defop.geometry.volumetric.surface.EmbeddedSurface, optional
        Write this fine surface, deformed by X, instead of the tetrahedra's boundary (surface formats only).

    Returns
    -------
    path : pathlib.Path
    """
    path = Path(path)
    kind = EXPORT_FORMATS.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"path must end in one of {sorted(EXPORT_FORMATS)}, got {path.name!r}")
    P = mesh.V if X is None else np.asarray(X, dtype=float)
    if P.shape != mesh.V.shape or not np.isfinite(P).all():
        raise ValueError(f"X must be finite with shape {mesh.V.shape} (a row per vertex), got {P.shape}")
    if kind == "volume" and mesh.dim == 3:
        if surface is not None:
            raise ValueError(f"surface= is written to .ply, .stl or .obj files, not to {path.suffix}")
        data = to_unstructured_grid(mesh.V, mesh.F, P)
    elif surface is not None:
        data = to_polydata(surface.V, surface.F, surface.deform(P))
    else:
        data = to_polydata(mesh.V, mesh.F, P).clean(point_merging=False)  # drops the interior vertices
    data.save(str(path))
    return path


def _add_handles(plotter, pv, P, handles, moving, radius):
    handles = np.asarray(handles)
    moving = np.ones(len(handles), bool) if moving is None else np.asarray(moving, bool)
    for idx, mv in zip(handles, moving, strict=True):
        c = P[idx] if P.shape[1] == 3 else np.append(P[idx], 0.0)
        plotter.add_mesh(pv.Sphere(radius=radius, center=c), color="#d62728" if mv else "#1f77b4")


def _add_shape(plotter, pv, mesh, P, scalars=None, cmap="viridis", show_edges=True, surface=None, color=FILL):
    """Add the (deformed) mesh, or its embedded fine surface, to the current subplot; returns the PolyData."""
    if surface is not None:
        poly = to_polydata(surface.V, surface.F, surface.deform(P))
    else:
        poly = to_polydata(mesh.V, mesh.F, P, scalars)
    style = dict(show_edges=show_edges, edge_color="#555555", line_width=0.5)
    if mesh.dim == 3:
        style.update(smooth_shading=surface is not None, specular=0.2)
    if scalars is None or surface is not None:
        plotter.add_mesh(poly, color=color, **style)
    else:
        plotter.add_mesh(poly, scalars="scalars", cmap=cmap, **style)
    return poly


def _place_camera(plotter, mesh, bounds, view=None):
    if mesh.dim == 2:
        plotter.view_xy()
        plotter.enable_parallel_projection()
    else:
        plotter.camera_position = view or "iso"
    plotter.reset_camera(bounds=bounds)


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
    surface=None,
    view=None,
):
    """A PyVista Plotter showing a (deformed) mesh with its handles: a planar mesh seen from above, a tetrahedral
    mesh as its boundary surface (or a fine embedded surface) in perspective.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        The rest mesh (triangles or tetrahedra).
    X : (n,d) numpy array, optional
        Deformed vertex positions; the rest pose when None.
    scalars : (n,) numpy array, or (m,) for triangles, optional
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
    surface : defop.geometry.volumetric.surface.EmbeddedSurface, optional
        In 3D, draw this fine surface deformed with the tetrahedra (``shape.surface``) instead of their boundary.
    view : str or camera position, optional
        In 3D, the camera (a PyVista camera position, e.g. ``"xy"``); ``"iso"`` when None.

    Returns
    -------
    plotter : pyvista.Plotter
    """
    pv = _pyvista()
    P = mesh.V if X is None else np.asarray(X, dtype=float)
    kw = {} if notebook is None else {"notebook": notebook}
    plotter = pv.Plotter(off_screen=off_screen, window_size=tuple(window_size), **kw)
    plotter.set_background("white")
    poly = _add_shape(plotter, pv, mesh, P, scalars, cmap, show_edges, surface)
    if handles is not None and len(handles):
        _add_handles(plotter, pv, P, handles, moving, 0.012 * mesh.bbox_diagonal)
    _place_camera(plotter, mesh, poly.bounds, view)
    return plotter


def render_mesh(mesh, X=None, screenshot=None, **kw):
    """Render a (deformed) mesh off-screen with PyVista and return the image.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n,d) numpy array, optional
        Deformed positions.
    screenshot : str or path, optional
        Also write the image there (PNG).
    **kw
        As for :func:`mesh_plotter` (``scalars``, ``handles``, ``moving``, ``window_size``, ``surface``, ...).

    Returns
    -------
    img : (H,W,3) uint8 numpy array
    """
    plotter = mesh_plotter(mesh, X, off_screen=True, **kw)
    return _snapshot(plotter, screenshot)


def _snapshot(plotter, screenshot=None, draw=None):
    """The plotter's image (also written to ``screenshot`` when given), after ``draw()``; the plotter is closed."""
    try:
        if draw is not None:
            draw()
        img = plotter.screenshot(filename=None if screenshot is None else str(screenshot), return_img=True)
    finally:
        plotter.close()
    return np.asarray(img)


def _check_poses(mesh, poses):
    """The poses as float arrays; ValueError unless they are a non-empty list of arrays shaped like ``mesh.V``."""
    poses = [np.asarray(p, dtype=float) for p in poses]
    if not poses or any(p.shape != mesh.V.shape for p in poses):
        raise ValueError(f"poses must be a non-empty list of {mesh.V.shape} arrays, got {[p.shape for p in poses]}")
    return poses


def _common_bounds(poses):
    """The VTK bounds (xmin, xmax, ymin, ymax, zmin, zmax) of all poses together (z = 0 for planar ones)."""
    bounds = np.array([p.min(0) for p in poses]).min(0), np.array([p.max(0) for p in poses]).max(0)
    return [v for pair in zip(*(np.append(b, 0.0)[:3] for b in bounds)) for v in pair]


def render_panels(
    mesh,
    poses,
    titles=None,
    handles=None,
    moving=None,
    colors=None,
    surface=None,
    view=None,
    ncols=None,
    panel_size=(360, 300),
    screenshot=None,
    show_edges=True,
):
    """Several poses of one mesh side by side (off-screen), one camera for all: e.g. the ground truth against
    operators with different Ψ (Fig. 7), or a gallery.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    poses : list of (n,d) numpy array
        Deformed positions, one panel each.
    titles : list of str, optional
    handles, moving, surface, view
        As in :func:`mesh_plotter`.
    colors : list of str, optional
        Surface colour per panel.
    ncols : int, optional
        Panels per row (all in one row when None).
    panel_size : (2,) tuple
        Pixels per panel.
    screenshot : path, optional
        Also write a PNG.
    show_edges : bool

    Returns
    -------
    img : (H,W,3) uint8 numpy array
    """
    pv = _pyvista()
    poses = _check_poses(mesh, poses)
    ncols = len(poses) if ncols is None else int(ncols)
    nrows = -(-len(poses) // ncols)
    size = (panel_size[0] * ncols, panel_size[1] * nrows)
    plotter = pv.Plotter(off_screen=True, shape=(nrows, ncols), window_size=size, border=False)
    box = _common_bounds(poses)

    def draw():
        for k, P in enumerate(poses):
            plotter.subplot(k // ncols, k % ncols)
            plotter.set_background("white")
            color = FILL if colors is None else colors[k]
            _add_shape(plotter, pv, mesh, P, show_edges=show_edges, surface=surface, color=color)
            if handles is not None and len(handles):
                _add_handles(plotter, pv, P, handles, moving, 0.012 * mesh.bbox_diagonal)
            if titles:
                plotter.add_text(titles[k], font_size=9, color="black")
            _place_camera(plotter, mesh, box, view)

    return _snapshot(plotter, screenshot, draw)


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
    window_size, screenshot
        As in :func:`mesh_plotter` and :func:`render_mesh`.
    cmap : str
        Colormap for the heights.

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

    def draw():
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

    return _snapshot(plotter, screenshot, draw)

"""Matplotlib figures of the lessons, from one import (presentation only; the core never imports this module).

The code lives by what it draws: :mod:`.draw` (meshes, handles, regions, outlines, keys), :mod:`.plot_energies`
(Fig. 6), :mod:`.plot_bases` (the bases and the gallery) and :mod:`.plot_trajectories` (Figs. 3, 5, 8 and 10);
every name is importable from here as well.
"""

from __future__ import annotations

from .draw import (
    FILL,
    FIXED,
    FLIP,
    MOVING,
    NAMES,
    REGION,
    cell_edges,
    figure_key,
    fill_triangles,
    key_legend,
    plot_deformation,
    plot_handle_zoom,
    plot_handles,
    plot_mesh,
    plot_outline,
    plot_regions,
    plot_shape,
    readable,
    region_outlines,
    shape_gallery,
    single_colormap,
)
from .plot_bases import (
    plot_bases_grid,
    plot_gallery,
)
from .plot_energies import (
    plot_convergence,
    plot_energies_figure,
    plot_energy_comparison,
)
from .plot_trajectories import (
    plot_error_over_m,
    plot_local_vs_global,
    plot_path_trajectories,
    plot_trajectories,
    plot_trajectories_3d,
)

__all__ = [
    "NAMES",
    "MOVING",
    "FIXED",
    "FILL",
    "REGION",
    "FLIP",
    "plot_mesh",
    "single_colormap",
    "fill_triangles",
    "plot_handles",
    "region_outlines",
    "plot_regions",
    "plot_shape",
    "shape_gallery",
    "plot_deformation",
    "plot_handle_zoom",
    "plot_outline",
    "key_legend",
    "figure_key",
    "cell_edges",
    "readable",
    "plot_bases_grid",
    "plot_gallery",
    "plot_energy_comparison",
    "plot_energies_figure",
    "plot_convergence",
    "plot_local_vs_global",
    "plot_trajectories",
    "plot_trajectories_3d",
    "plot_path_trajectories",
    "plot_error_over_m",
]

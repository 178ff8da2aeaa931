"""Matplotlib figures of the lessons, from one import (presentation only; the core never imports this module).

The code lives by what it draws: :mod:`.draw` (meshes, handles, regions, outlines, keys), :mod:`.plot_energies`
(Fig. 6), :mod:`.plot_bases` (the bases and the gallery) and :mod:`.plot_trajectory_maps` (Figs. 3, 5, 8 and 10);
every name is importable from here as well.
"""

from __future__ import annotations

from . import draw, plot_bases, plot_energies, plot_trajectory_maps
from .draw import *  # noqa: F403 (the names in draw.__all__)
from .plot_bases import *  # noqa: F403
from .plot_energies import *  # noqa: F403
from .plot_trajectory_maps import *  # noqa: F403

__all__ = [*draw.__all__, *plot_bases.__all__, *plot_energies.__all__, *plot_trajectory_maps.__all__]

"""Pictures (layer 6): matplotlib plots (:mod:`.plot` gathers :mod:`.draw`, :mod:`.plot_bases`,
:mod:`.plot_energies` and :mod:`.plot_trajectory_maps`; :mod:`.plot_peers`; labels clear of each other, :mod:`.labels`),
PyVista rendering (:mod:`.render`; the off-screen window, :mod:`.headless`) and image warping (:mod:`.warp`).
Nothing below this layer imports a plotting library.
"""

from ..lazy import attach

_MODULES = (
    "branches",
    "draw",
    "headless",
    "labels",
    "plot",
    "plot_bases",
    "plot_energies",
    "plot_peers",
    "plot_trajectory_maps",
    "render",
    "warp",
)
_NAMES = {}

__getattr__, __dir__ = attach(__name__, _MODULES, _NAMES)

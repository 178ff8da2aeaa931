"""Pictures (layer 6): matplotlib plots (:mod:`.plot`, :mod:`.plot_peers`; labels clear of each other,
:mod:`.labels`), headless PyVista rendering (:mod:`.render`) and image warping (:mod:`.warp`).
Nothing below this layer imports a plotting library.
"""

from ..lazy import attach

_MODULES = ("branches", "labels", "plot", "plot_peers", "render", "warp")
_NAMES = {}

__getattr__, __dir__ = attach(__name__, _MODULES, _NAMES)

"""Pictures (layer 6): matplotlib plots (:mod:`.plot`, :mod:`.plot_peers`; labels clear of each other,
:mod:`.labels`), headless PyVista rendering (:mod:`.render`) and image warping (:mod:`.warp`).
Nothing below this layer imports a plotting library.
"""

from importlib import import_module

_MODULES = ("labels", "plot", "plot_peers", "render", "warp")
_NAMES = {}


def __getattr__(name):  # modules drawn in on first use: matplotlib and PyVista only when a picture is drawn
    if name in _MODULES:
        module = import_module(f".{name}", __name__)
        globals()[name] = module
        return module
    if name in _NAMES:
        value = getattr(import_module(f".{_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_MODULES) + list(_NAMES))

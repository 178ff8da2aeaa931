"""Interactive editing (layer 7): the editor's state (:mod:`.state`, numpy only), the in-browser view
(:class:`BrowserEditor`, :mod:`.browser`), the matplotlib widget controls (:mod:`.widgets`) and the standalone
HTML page (:mod:`.export`).
"""

from importlib import import_module

_MODULES = ("browser", "export", "state", "widgets")
_NAMES = {"BrowserEditor": "browser", "EditorState": "state", "to_html": "export"}


def __getattr__(name):  # modules drawn in on first use: anywidget, ipywidgets and matplotlib only when an editor opens
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

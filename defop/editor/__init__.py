"""Interactive editing (layer 7): the editor's state (:mod:`.state`, numpy only), the in-browser view
(:class:`BrowserEditor`, :mod:`.browser`), the matplotlib widget controls (:mod:`.widgets`) and the standalone
HTML page (:mod:`.export`).
"""

from ..lazy import attach

_MODULES = ("browser", "export", "state", "widgets")
_NAMES = {"BrowserEditor": "browser", "EditorState": "state", "to_html": "export"}

__getattr__, __dir__ = attach(__name__, _MODULES, _NAMES)

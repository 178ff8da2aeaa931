"""Interactive editing (layer 7): the editor's state (:mod:`.state`, numpy only; its logic as pure functions in
:mod:`.logic`), the in-browser view (:class:`BrowserEditor`, :mod:`.browser`), the matplotlib widget controls
(:mod:`.widgets`) and the standalone HTML page (:mod:`.export`): for a 2D operator the 2D editor, for a 3D operator
(tetrahedra) the 3D page (``static/defop_solid.js`` with the vendored three.js, ``static/three/README.md``), for a
:class:`~defop.operator.movable.MovableOp` the 2D page or the 3D page with its rest mode (:mod:`.movable_page`,
``static/defop_movable.js``; the editor state's rest mode is :mod:`.rest`); your own model's file to a trained page
in one call (:func:`own_model`, :mod:`.model_page`; ``python -m defop page``).
"""

from ..lazy import attach

_MODULES = ("browser", "export", "logic", "model_page", "movable_page", "rest", "state", "widgets")
_NAMES = {"BrowserEditor": "browser", "EditorState": "state", "to_html": "export", "own_model": "model_page"}

__getattr__, __dir__ = attach(__name__, _MODULES, _NAMES)

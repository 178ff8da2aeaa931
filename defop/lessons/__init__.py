"""The lessons' own computations (top layer, beside :mod:`defop.figures`): data behind individual figures of the
notebooks that the library's general modules do not cover.

- :mod:`.figure_data`: Figs. 2, 3, 5, 7, 8, 9 and 10 (column scans, arc samples, fit diagnostics, the subspace
  floor, grid errors, subset fits, local rotations);
- :mod:`.random_branches`: a seeded generator of bistable strips nobody tuned, and their acceptance (notebook 15).

The library below never imports it (import-linter contracts); the lessons call it as ``dop.lessons.figure_data``.
"""

from ..lazy import attach

_MODULES = ("figure_data", "random_branches")

__getattr__, __dir__ = attach(__name__, _MODULES)

"""Sphinx configuration of the defop book (``make book`` → ``build/book/index.html``).

The site is built from the notebooks' stored outputs: myst-nb executes nothing (``nb_execution_mode = "off"``).
Nothing is fetched at build or at view time: MathJax is vendored in ``_static/mathjax`` (see VENDORED.txt there),
myst-nb's CDN script for widget state is switched off, and the theme (sphinx-book-theme on pydata-sphinx-theme)
ships its own fonts and scripts. ``docs/build.py`` stages this folder with the notebooks, figures and the
benchmarks README into ``build/book-src`` and runs Sphinx there, so a build writes nothing into the repository
outside the git-ignored ``build/``.
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from pathlib import Path

import sphinx.ext.autosummary as autosummary_module

# autodoc imports the package the build was staged from (docs/build.py sets DEFOP_BOOK_ROOT to the worktree)
ROOT = Path(os.environ.get("DEFOP_BOOK_ROOT", Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "defop"
author = "the defop developers"
copyright = "the defop developers, MIT licence"
html_title = "defop: simple approximations of planar deformation operators"

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
]

root_doc = "index"
exclude_patterns = ["_build", "_static/**", "_templates/**", "_extra/**", "benchmarks/**", "figures/**"]
exclude_patterns += ["**/.ipynb_checkpoints"]
templates_path = ["_templates"]
suppress_warnings = ["myst.header"]  # notebooks start at "#" and some skip a level for their sub-headings

# --- notebooks: stored outputs only ---------------------------------------------------------------------------
nb_execution_mode = "off"
nb_ipywidgets_js = {}  # no requirejs / widget-state script from a CDN (the lessons store no widget state)
nb_merge_streams = True
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# --- maths: MathJax 3, served from this site ------------------------------------------------------------------
MATHJAX_VERSION = "3.2.2"
mathjax_path = "mathjax/tex-chtml.js"  # relative to _static
mathjax3_config = {"options": {"enableMenu": False}}  # the menu would lazily load a11y/sre scripts

# --- API reference from the numpy docstrings --------------------------------------------------------------------
autosummary_generate = True
autosummary_imported_members = False
# a package's __all__ re-exports its modules' names: document each object once, where it is defined
autodoc_default_options = {"members": True, "show-inheritance": True, "ignore-module-all": True}
autodoc_typehints = "none"  # the numpy docstrings give the types and shapes
autodoc_member_order = "bysource"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True
warnings.filterwarnings("ignore", category=DeprecationWarning)
# the one-line summaries of the API tables end at a sentence's full stop, not at the paper's "Eq." or "Fig."
autosummary_module.WELL_KNOWN_ABBREVIATIONS += ("Eq.", "Eqs.", "Fig.", "Figs.", "Prop.", "App.", "Sec.", "vs.", "cf.")

# --- theme: local assets only -----------------------------------------------------------------------------------
html_theme = "sphinx_book_theme"
html_static_path = ["_static"]
html_extra_path = ["_extra"]  # the standalone editor pages (docs/build.py copies figures/*.html there)
html_theme_options = {
    "use_download_button": False,
    "use_fullscreen_button": True,
    "use_repository_button": False,
    "use_issues_button": False,
    "use_edit_page_button": False,
    "show_toc_level": 2,
    "home_page_in_toc": True,
    "navigation_with_keys": False,
}
# the figures are drawn on white; with no mode at all the theme logs a console error on a first visit
html_context = {"default_mode": "light"}
html_show_sourcelink = False
html_copy_source = False
html_last_updated_fmt = None


# The docstrings write norms and sizes as |Ψ|, |x|: in reStructuredText that is a substitution reference. Escape
# such a pair of bars (no space inside them; table rows "| a | b |" have spaces and are left alone).
_NORM = re.compile(r"(?<![\\|`])\|(?=[^\s|`])([^|\n`]*?[^\s|\\`])\|(?![|_`])")
_ROW = re.compile(r"^(\s*)\|(.*)\|\s*$")
_RULE = re.compile(r"^\s*\|[\s:|-]*-[\s:|-]*\|\s*$")


def _cells(line):
    return [c.strip() for c in _ROW.match(line)[2].split("|")]


def _markdown_tables(lines):
    """A Markdown pipe table in a docstring (header row, |---| rule, rows) as an rST list-table."""
    out, i = [], 0
    while i < len(lines):
        if i + 1 < len(lines) and _ROW.match(lines[i]) and _RULE.match(lines[i + 1]):
            indent, rows = _ROW.match(lines[i])[1], [_cells(lines[i])]
            i += 2
            while i < len(lines) and _ROW.match(lines[i]):
                rows.append(_cells(lines[i]))
                i += 1
            out += [f"{indent}.. list-table::", f"{indent}   :header-rows: 1", ""]
            for row in rows:
                out += [f"{indent}   * - {row[0]}"] + [f"{indent}     - {cell}" for cell in row[1:]]
            out.append("")
        else:
            out.append(lines[i])
            i += 1
    return out


def _docstring_to_rst(app, what, name, obj, options, lines):
    lines[:] = [_NORM.sub(r"\\|\1\\|", line) for line in _markdown_tables(lines)]


def setup(app):
    app.connect("autodoc-process-docstring", _docstring_to_rst)

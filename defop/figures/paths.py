"""Where the main job finds the notebooks and writes the figures and the timing record."""

from __future__ import annotations

import fnmatch
from pathlib import Path

__all__ = ["ROOT", "NOTEBOOKS", "FIGURES", "RUNTIMES", "notebooks"]

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = ROOT / "notebooks"
FIGURES = ROOT / "figures"
RUNTIMES = FIGURES / "runtimes.json"


def notebooks(only=None, directory=None):
    """The notebooks to run, in order.

    Parameters
    ----------
    only : str or list of str, optional
        Glob patterns on the file name (``"02_*"``); all when None.
    directory : path

    Returns
    -------
    paths : list of pathlib.Path
    """
    directory = NOTEBOOKS if directory is None else directory
    paths = sorted(Path(directory).glob("[0-9][0-9]_*.ipynb"))
    if only:
        pats = [only] if isinstance(only, str) else list(only)
        paths = [p for p in paths if any(fnmatch.fnmatch(p.name, pat) or pat in p.stem for pat in pats)]
        if not paths:
            raise ValueError(f"no notebook matches {pats}; known: {[p.name for p in notebooks(directory=directory)]}")
    return paths

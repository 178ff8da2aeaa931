"""The main job: regenerate every figure by executing the notebooks (``python -m defop figures``).

Each notebook in ``notebooks/`` is executed with nbclient, in its own directory, in full mode
(``DEFOP_FAST`` unset) unless ``fast=True``. Full runs store their outputs back into the
notebook, as the project's notebooks keep outputs from full runs. Figures are written by the
notebooks themselves into ``figures/``.
"""

from __future__ import annotations

import fnmatch
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
FIGURES = ROOT / "figures"


def notebooks(only=None, directory=NOTEBOOKS):
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
    paths = sorted(Path(directory).glob("[0-9][0-9]_*.ipynb"))
    if only:
        pats = [only] if isinstance(only, str) else list(only)
        paths = [p for p in paths if any(fnmatch.fnmatch(p.name, pat) or pat in p.stem for pat in pats)]
        if not paths:
            raise ValueError(f"no notebook matches {pats}; known: {[p.name for p in notebooks(directory=directory)]}")
    return paths


def run_notebook(path, fast=False, store=None, timeout=3600, kernel_name="python3"):
    """Execute one notebook with nbclient.

    Parameters
    ----------
    path : path
        The ``.ipynb`` file.
    fast : bool
        Run with ``DEFOP_FAST=1``.
    store : bool, optional
        Write the executed notebook back; default: only for full runs.
    timeout : float
        Per-cell timeout in seconds.

    Returns
    -------
    seconds : float
    """
    import nbformat
    from nbclient import NotebookClient

    path = Path(path)
    store = (not fast) if store is None else store
    nb = nbformat.read(path, as_version=4)
    old = os.environ.get("DEFOP_FAST")
    if fast:
        os.environ["DEFOP_FAST"] = "1"
    else:
        os.environ.pop("DEFOP_FAST", None)
    t0 = time.perf_counter()
    try:
        client = NotebookClient(
            nb, timeout=timeout, kernel_name=kernel_name, resources={"metadata": {"path": str(path.parent)}}
        )
        client.execute()
    finally:
        if old is None:
            os.environ.pop("DEFOP_FAST", None)
        else:
            os.environ["DEFOP_FAST"] = old
    seconds = time.perf_counter() - t0
    if store:
        nbformat.write(nb, path)
    return seconds


def regenerate(only=None, fast=False, store=None, timeout=3600, clean=False, log=print):
    """Run the notebooks and report which figures each wrote.

    Parameters
    ----------
    only : str or list of str, optional
        Notebook name patterns.
    fast : bool
        CI-sized sample counts (``DEFOP_FAST=1``).
    store : bool, optional
        Store outputs into the notebooks (default: full runs only).
    timeout : float
        Per-cell timeout in seconds.
    clean : bool
        A clean run: delete the figures and empty the cache of ground truths and operators
        (``DEFOP_CACHE``) first, so everything is recomputed.
    log : callable

    Returns
    -------
    report : list of (str, float, list of str)
        Notebook name, seconds, figures written.
    """
    from . import render

    render.configure_headless()  # exported to the kernels through the environment
    FIGURES.mkdir(exist_ok=True)
    if clean:
        for pattern in ("*.png", "table1.*"):
            for f in FIGURES.glob(pattern):
                f.unlink()
        from .config import cache_dir

        folder = cache_dir()
        if folder is not None:
            removed = 0
            for f in list(folder.glob("gt-*.npz")) + list(folder.glob("op-*.npz")) + list(folder.glob("traj-*")):
                f.unlink()
                removed += 1
            log(f"clean run: removed the figures and {removed} cached results from {folder}")
    report = []
    for path in notebooks(only):
        before = {f: f.stat().st_mtime for f in FIGURES.glob("*")}
        log(f"running {path.name} ({'fast' if fast else 'full'} mode) ...")
        seconds = run_notebook(path, fast=fast, store=store, timeout=timeout)
        written = sorted(f.name for f in FIGURES.glob("*") if before.get(f) != f.stat().st_mtime)
        log(f"  {seconds:7.1f} s  -> {', '.join(written) or '(no figure)'}")
        report.append((path.name, seconds, written))
    total = sum(s for _, s, _ in report)
    log(f"{len(report)} notebooks in {total:.0f} s; figures in {FIGURES}")
    return report

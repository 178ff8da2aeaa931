"""Executing one notebook with nbclient: its kernel's environment, its progress bars forwarded, its CPU seconds
counted, a failing or hanging cell named (:func:`run_notebook`)."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path

from .paths import FIGURES
from .storing import normalise

__all__ = ["CELL_TIMEOUT", "NotebookError", "run_notebook"]


#: per-cell timeout of the main job: the longest cell (07_octopus, training two 1,000-sample S-ARAP operators on the
#: octopus from an empty cache) took more than 600 s on this 2-core machine under load; a hang still fails in 30 min
CELL_TIMEOUT = 1800


class NotebookError(RuntimeError):
    """A notebook failed in the main job; the message names the notebook and the cell."""


def client_class():
    from nbclient import NotebookClient

    class Client(NotebookClient):
        """nbclient that forwards progress bars (stderr text with carriage returns) to a terminal."""

        progress_stream = None
        progress_prefix = None  # lessons side by side: each line of a bar starts with its lesson's name
        current_cell = None
        cpu_seconds = None

        def output(self, outs, msg, display_id, cell_index):
            content = msg.get("content", {})
            if msg["msg_type"] == "stream" and content.get("name") == "stderr" and "\r" in content.get("text", ""):
                if self.progress_stream is not None:
                    text = content["text"]
                    lead = "" if self.progress_prefix is None else self.progress_prefix + " "
                    if self.progress_prefix is not None or not self.progress_stream.isatty():  # one line per update
                        text = "".join(lead + s.strip() + "\n" for s in text.split("\r") if s.strip())
                    self.progress_stream.write(text)
                    self.progress_stream.flush()
                return None  # a progress bar is never stored in the notebook
            return super().output(outs, msg, display_id, cell_index)

        def count_cpu(self, **_):
            """After each cell: the CPU seconds of the kernel and its workers so far (:func:`tree_cpu`)."""
            process = getattr(getattr(self.km, "provisioner", None), "process", None)
            seconds = None if process is None else tree_cpu(process.pid)
            self.cpu_seconds = self.cpu_seconds if seconds is None else seconds

    return Client


def tree_cpu(pid):
    """CPU seconds of process ``pid`` and its descendants, live or ended and waited for; None when unknown."""
    try:
        import psutil

        root = psutil.Process(pid)
        total = 0.0
        for proc in [root, *root.children(recursive=True)]:
            with contextlib.suppress(psutil.NoSuchProcess):
                t = proc.cpu_times()
                total += t.user + t.system + t.children_user + t.children_system
        return total
    except Exception:  # no psutil, the kernel gone: no CPU count, the wall seconds stay
        return None


def make_client(nb, path, timeout, kernel_name, progress, prefix):
    """The nbclient client of :func:`run_notebook`: it runs in the notebook's folder, forwards progress bars, counts
    CPU seconds after each cell and knows the cell it runs (for the messages)."""
    client = client_class()(
        nb,
        timeout=timeout,
        kernel_name=kernel_name,
        resources={"metadata": {"path": str(path.parent)}},
        record_timing=False,  # widget state stays on: nbclient's Output-widget support needs it (normalise drops it)
    )
    client.progress_stream, client.progress_prefix = progress, prefix
    client.on_cell_executed = client.count_cpu
    client.on_cell_start = lambda cell, cell_index: setattr(client, "current_cell", (cell, cell_index))
    return client


def describe_cell(name, cell, index):
    first = next((ln for ln in cell.source.splitlines() if ln.strip() and not ln.startswith("# NBVAL")), "")
    return f"{name}, cell {index} ({first.strip()[:70]!r})"


def run_notebook(
    path,
    fast=False,
    store=None,
    timeout=CELL_TIMEOUT,
    kernel_name="python3",
    progress=sys.stderr,
    prefix=None,
    env=None,
    measured=None,
):
    """Execute one notebook with nbclient.

    Parameters
    ----------
    path : path
        The ``.ipynb`` file.
    fast : bool
        Run with ``DEFOP_FAST=1``.
    store : bool, optional
        Write the executed notebook back (normalised); default: only for full runs.
    timeout : float
        Per-cell timeout in seconds.
    progress : file-like or None
        Where the kernel's progress bars go.
    prefix : str, optional
        Start every progress line with it (lessons side by side share the terminal).
    env : dict, optional
        More environment for the kernel (None: unset).
    measured : dict, optional
        Receives ``"cpu"``: the CPU seconds of the kernel and its workers up to its last cell (None when they cannot
        be read), also when a cell fails.

    Returns
    -------
    seconds : float

    Raises
    ------
    NotebookError
        A cell raised, timed out or the kernel died; the message names the notebook and the cell.
    """
    import nbformat

    path = Path(path)
    store = (not fast) if store is None else store
    nb = nbformat.read(path, as_version=4)
    env = {**kernel_env(fast, progress, lines=prefix is not None), **(env or {})}
    old = {k: os.environ.get(k) for k in env}
    set_env(env)
    client = make_client(nb, path, timeout, kernel_name, progress, prefix)
    t0 = time.perf_counter()
    try:
        client.execute()
    except Exception as exc:
        where = describe_cell(path.stem, *client.current_cell) if client.current_cell else path.stem
        kind = f"timed out after {timeout:.0f} s" if "Timeout" in type(exc).__name__ else "failed"
        detail = str(exc).strip().splitlines()
        raise NotebookError(f"{where} {kind}: {type(exc).__name__}: {detail[-1] if detail else ''}") from exc
    finally:
        set_env(old)
        if measured is not None:
            measured["cpu"] = client.cpu_seconds
    seconds = time.perf_counter() - t0
    if store:
        path.write_text(nbformat.writes(normalise(nb)) + "\n")
    return seconds


def kernel_env(fast, progress, lines=False):
    """The environment the kernel runs in (None: unset): fast or full mode, where figures go, text progress bars
    (``lines``: one line per update, as for a log file)."""
    env = {
        "DEFOP_FAST": "1" if fast else None,
        "DEFOP_FIGURES": None if fast else str(FIGURES),  # only full runs write the repository's figures/
        "DEFOP_PROGRESS": "text",
        "TQDM_MININTERVAL": None,
    }
    if progress is not None and (lines or not progress.isatty()):
        env["TQDM_MININTERVAL"] = "15"  # a log file gets a line every 15 s, not every 0.1 s
    return env


def set_env(values):
    for key, value in values.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value

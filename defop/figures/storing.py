"""Notebooks as stored by the main job: normalised (nbstripout, outputs kept) so that the same content gives the same
file on every machine, and widget outputs reduced to their static picture and text line."""

from __future__ import annotations

from pathlib import Path

__all__ = ["STRIP_KEYS", "WIDGET_VIEW", "normalise", "normalise_files"]

# nbstripout's own defaults (its command line adds them) plus the interpreter version, which the kernel
# writes on every run and differs from machine to machine
STRIP_KEYS = (
    "metadata.signature",
    "metadata.widgets",
    "metadata.language_info.version",
    "cell.metadata.collapsed",
    "cell.metadata.ExecuteTime",
    "cell.metadata.execution",
    "cell.metadata.heading_collapsed",
    "cell.metadata.hidden",
    "cell.metadata.scrolled",
)
WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"


def _static_outputs(outputs):
    """Widget outputs keep their static fallback (a picture and its text line); a widget with no picture
    (a progress bar frozen where it was, a raw ``VBox(children=…`` repr) is dropped: without a kernel it
    shows nothing true."""
    kept = []
    for out in outputs:
        data = out.get("data")
        if data and WIDGET_VIEW in data:
            data.pop(WIDGET_VIEW)
            if set(data) <= {"text/plain"}:
                continue
        kept.append(out)
    return kept


def _merge_streams(outputs):
    """Adjacent stream outputs of one name (stdout, stderr) as one: how a cell's prints are split into messages
    depends on the kernel's timing (a loaded machine, lessons side by side), not on what they print. nbval merges
    them as well before it compares."""
    merged = []
    for out in outputs:
        last = merged[-1] if merged else None
        if last is not None and out.get("output_type") == last.get("output_type") == "stream":
            if out.get("name") == last.get("name"):
                text = last["text"] if isinstance(last["text"], str) else "".join(last["text"])
                last["text"] = text + (out["text"] if isinstance(out["text"], str) else "".join(out["text"]))
                continue
        merged.append(out)
    return merged


def normalise(nb):
    """Normalise a notebook for storing: the same content gives the same file on every machine.

    nbstripout (the Jupyter community's notebook cleaner, used by many projects as a git filter) with
    outputs and cell ids kept: it drops per-cell timing metadata, stored widget state and the interpreter
    version, and numbers the code cells 1, 2, ... Widget outputs keep only their static picture and text line, and
    adjacent prints to one stream are one output.

    Parameters
    ----------
    nb : nbformat.NotebookNode
        Changed in place.

    Returns
    -------
    nb : nbformat.NotebookNode
    """
    from nbstripout import strip_output

    strip_output(nb, keep_output=True, keep_count=False, keep_id=True, extra_keys=list(STRIP_KEYS))
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    for count, cell in enumerate(code, start=1):
        cell.outputs = _merge_streams(_static_outputs(cell.outputs))
        # numbered 1, 2, ... as a run-all numbers them (the same on every machine): nbval only compares the
        # outputs of cells with a count ("Unrun reference cell has outputs" otherwise)
        cell.execution_count = count
    return nb


def normalise_files(paths):
    """Normalise notebooks on disk (``python -m defop normalise``); returns the paths that changed."""
    import nbformat

    changed = []
    for path in map(Path, paths):
        before = path.read_text()
        nb = normalise(nbformat.reads(before, as_version=4))
        after = nbformat.writes(nb) + "\n"
        if after != before:
            path.write_text(after)
            changed.append(path)
    return changed

"""Looking after the cache directory (:mod:`defop.training.cache`): what it holds (``python -m defop cache``) and
removing the entries no version of this code reads (``python -m defop cache --prune``).

An entry's key hashes the versions it was computed with (:func:`defop.training.cache.key`: ``defop.__version__``,
the entry layout and :data:`defop.variational.solver.VERSION`), so once one of them changes no reader asks for it
again; its stamp names them (:data:`defop.training.cache.VERSION_TAG`), which is how :func:`scan` tells. Each file
of the directory gets one status:

``current``
    Stamped with this code's versions: kept.
``other version``
    Stamped with other versions: no version of this code reads it. Pruned.
``no digest``
    Written by a defop before entries carried their digest: every reader recomputes it. Pruned.
``damaged``, ``misnamed``
    Its stamp cannot be read, or names another entry (a copied or renamed file): a reader would remove it. Pruned.
``stale temporary``, ``free lock``
    The temporary file of a writer killed midway, or the ``.cold-*`` folder of a main job's lesson killed midway
    (older than :data:`defop.training.cache.STALE_SECONDS`); a lock file no process holds. Pruned.
``untagged``
    Stamped with its digest but not its versions (written before stamps named them): it may still be read.
    Pruned only when asked (``--untagged``).
``in use``, ``foreign``
    A writer's temporary file or a held lock; a file that is no cache entry. Never touched.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import shutil
import time
from pathlib import Path

from . import cache as cache_mod
from . import cache_files

__all__ = ["Entry", "PRUNED", "classify", "prune", "scan", "summary"]

#: the statuses :func:`prune` removes (``"untagged"`` too when asked)
PRUNED = ("other version", "no digest", "damaged", "misnamed", "stale temporary", "free lock")
_ENTRY = re.compile(r"^(?P<kind>.+)-(?P<key>[0-9a-f]{20})\.npz$")


@dataclasses.dataclass(frozen=True)
class Entry:
    """One file of the cache directory: its path, kind (``gt``, ``op``, ...; ``""`` for no entry), size in bytes,
    status (see the module docstring) and why."""

    path: Path
    kind: str
    size: int
    status: str
    why: str = ""


def classify(path, now=None):
    """The :class:`Entry` of the file ``path`` of a cache directory (a pathlib.Path)."""
    now = time.time() if now is None else now
    try:
        size = path.stat().st_size
    except FileNotFoundError:  # removed meanwhile by another process
        return Entry(path, "", 0, "in use", "gone")
    name = path.name
    if name.startswith(".") and name.endswith(".lock"):
        return Entry(path, name[1:-5].rsplit("-", 1)[0], size, _lock_status(path))
    if name.startswith(".") and (name.endswith(".tmp.npz") or (name.startswith(".cold-") and path.is_dir())):
        stale = now - path.stat().st_mtime > cache_mod.STALE_SECONDS
        return Entry(path, "", size, "stale temporary" if stale else "in use", "a writer's temporary file or folder")
    m = _ENTRY.match(name)
    if m is None or not path.is_file():
        return Entry(path, "", size, "foreign", "not a cache entry")
    try:
        digest, tag = cache_files.read_stamp(path)
    except (cache_files.CorruptEntry, OSError) as exc:
        return Entry(path, m["kind"], size, "damaged", str(exc))
    if digest is None:
        return Entry(path, m["kind"], size, "no digest", "written before entries carried their digest")
    if digest != cache_mod.digest(m["kind"], m["key"]):
        return Entry(path, m["kind"], size, "misnamed", f"its stamp names {digest!r}")
    if tag is None:
        return Entry(path, m["kind"], size, "untagged", "written before stamps named the versions")
    if tag != cache_mod.VERSION_TAG:
        return Entry(path, m["kind"], size, "other version", tag)
    return Entry(path, m["kind"], size, "current")


def _lock_status(path):
    """``"free lock"`` when no process holds the lock file ``path`` (checked by taking it, then letting it go)."""
    fd = cache_files.acquire_lock(path, wait=False)
    if fd is None:
        return "in use"
    os.close(fd)
    return "free lock"


def scan(folder):
    """Every file of the cache directory ``folder``, classified: a list of :class:`Entry`, sorted by name."""
    now = time.time()
    return [classify(p, now) for p in sorted(Path(folder).iterdir(), key=lambda p: p.name)]


def prune(folder, dry_run=False, untagged=False):
    """Remove the entries no version of this code reads (the statuses in :data:`PRUNED`).

    Parameters
    ----------
    folder : path
        The cache directory.
    dry_run : bool
        Remove nothing; return what would be removed.
    untagged : bool
        Also remove the ``untagged`` entries (written before stamps named their versions; they may still be read).

    Returns
    -------
    removed : list of Entry
    """
    doomed = [e for e in scan(folder) if e.status in PRUNED or (untagged and e.status == "untagged")]
    if dry_run:
        return doomed
    removed = []
    for e in doomed:
        fd = cache_files.acquire_lock(e.path, wait=False) if e.status == "free lock" else None
        if e.status == "free lock" and fd is None:
            continue  # taken meanwhile: in use
        with contextlib.suppress(FileNotFoundError):
            if e.path.is_dir():  # the empty cache of its own a killed main job's lesson left
                shutil.rmtree(e.path)
            else:
                e.path.unlink()
            removed.append(e)
        if fd is not None:
            os.close(fd)
    return removed


def _megabytes(n):
    return f"{n / 2**20:.1f} MB"


def summary(entries):
    """Lines describing ``entries`` (from :func:`scan`): the total, then the count and size by kind and by status."""
    total = sum(e.size for e in entries)
    lines = [f"{len(entries)} files, {_megabytes(total)}"]
    for field in ("kind", "status"):
        groups = {}
        for e in entries:
            n, size = groups.get(getattr(e, field) or "-", (0, 0))
            groups[getattr(e, field) or "-"] = (n + 1, size + e.size)
        lines.append(f"by {field}:")
        lines += [f"  {k:16s} {n:6d}  {_megabytes(s):>10s}" for k, (n, s) in sorted(groups.items())]
    return lines

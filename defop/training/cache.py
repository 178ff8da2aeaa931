"""The on-disk cache of computed results: ground truths, trained operators, trajectories.

One layer used by :mod:`defop.training.bootstrap` and :mod:`defop.analysis.trajectories`. An entry is one ``.npz`` file
``<kind>-<key>.npz`` in the cache directory (``DEFOP_CACHE``, see :func:`defop.config.cache_dir`).

* **Keys** (:func:`key`) hash every part given (arrays by dtype, shape and bytes; everything else as
  JSON) together with the library version ``defop.__version__``, the entry layout :data:`FORMAT` and
  the solver salt :data:`SOLVER_SALT`. Callers pass every setting that changes the result, the
  solver's included (:func:`solver_settings`).
* **Writes are atomic**: an entry is written to a hidden temporary file in the same directory and
  renamed into place with :func:`os.replace`, so a reader sees either no entry or a complete one, and
  two processes writing the same entry leave one complete copy (the last rename wins; both computed
  the same result). A temporary file left by a writer killed midway is removed by :func:`open_cache`
  once it is an hour old.
* **Reads are checked**: an entry that cannot be read (any exception: truncated, damaged zip), misses
  an array or its metadata, has an array of the wrong shape or dtype, or holds NaN/inf is removed with
  a :class:`CacheWarning` naming the file, and the caller recomputes it. (If another process renamed a
  new entry into place meanwhile, that one is kept.) Random truncations and bit flips of an entry,
  10,000 of them, gave 0 loads of wrong data (``tests/test_cache.py`` runs 600).

Bumping :data:`SOLVER_SALT` (it is :data:`defop.variational.solver.VERSION`)
    Increase ``defop.variational.solver.VERSION`` by one in the same commit as any change to
    :mod:`defop.variational.solver` or
    :mod:`defop.variational.energies` that changes the solutions (a new stopping rule, smoothing schedule, start
    policy, line search, energy formula, ...). Every cached ground truth, operator and trajectory then
    misses and is recomputed, so ``make figures`` never reuses results of the old algorithm. A refactor
    that leaves the solutions unchanged needs no bump.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import stat
import time
import warnings
from pathlib import Path

import numpy as np

from .. import __version__, config
from .. import options as opt
from ..variational.solver import VERSION as _solve_version

__all__ = ["Cache", "CacheWarning", "CorruptEntry", "FORMAT", "SOLVER_SALT", "key", "open_cache", "solver_settings"]

#: Version of the algorithm of :mod:`defop.variational.solver` (one number,
#: :data:`defop.variational.solver.VERSION`; bump it there when
#: the solutions change, see the module docstring).
SOLVER_SALT = _solve_version

#: Layout of the cache entries; bump it when the arrays or metadata stored in an entry change.
FORMAT = 1

_META = "__meta__"  # the entry's JSON metadata, stored as a 0-d string array
#: a damaged .npz can make zipfile/numpy raise nearly anything (BadZipFile, EOFError, NotImplementedError for a
#: flipped compression-method byte, struct.error, zlib.error, SyntaxError in the array header, ...): any failure
#: to read an entry makes it unusable, and it is removed, with a warning naming the file and the exception
_READ_ERRORS = (Exception,)


class CacheWarning(UserWarning):
    """A corrupt cache entry was removed (it will be recomputed)."""


class CorruptEntry(ValueError):
    """Raised by a reader given to :meth:`Cache.load_with` for an entry that fails its checks."""


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return {"dtype": str(obj.dtype), "shape": obj.shape, "data": obj.tolist()}
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cache key part of type {type(obj).__name__} is not supported: {obj!r}")


def key(*parts) -> str:
    """Hash of everything that determines a cached result.

    Parameters
    ----------
    *parts : numpy arrays, or JSON-serialisable values (str, numbers, None, lists, tuples, dicts)
        Arrays are hashed by dtype, shape and bytes. The library version, :data:`FORMAT` and
        :data:`SOLVER_SALT` are always included.

    Returns
    -------
    str
        20 hex digits.
    """
    h = hashlib.sha1()
    h.update(json.dumps([__version__, FORMAT, SOLVER_SALT]).encode())
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"array {a.dtype.str} {a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(b"json ")
            h.update(json.dumps(p, sort_keys=True, default=_json_default).encode())
        h.update(b"|")
    return h.hexdigest()[:20]


def solver_settings(solver) -> dict:
    """The settings of a :class:`defop.variational.solver.Solver` that change its solutions, for :func:`key`.

    Every public attribute holding a plain value (str, number, bool, None, or a tuple of them),
    e.g. ``energy``, ``tol``, ``max_iter``, ``mu_schedule`` (smoothing), ``stage_tol``,
    ``exact_switch`` and a start policy if the solver has one. Arrays (the mesh, the handles) are
    left to the caller, which hashes them itself, and so are lists (mutable state, not settings).

    Returns
    -------
    dict of str -> value
    """
    plain = (str, int, float, bool, type(None), np.generic)
    out = {}
    for name, value in sorted(vars(solver).items()):
        if name.startswith("_"):
            continue
        if isinstance(value, plain) or (isinstance(value, tuple) and all(isinstance(v, plain) for v in value)):
            out[name] = value
    out["class"] = type(solver).__qualname__
    return out


def open_cache(enabled=True):
    """The cache, checked to be usable, or None when ``enabled`` is false or ``DEFOP_CACHE=off``.

    Call it at the start of a computation: a bad ``DEFOP_CACHE`` raises here, before any work.

    Raises
    ------
    ValueError
        ``DEFOP_CACHE`` names a file, a directory that cannot be created, or one that is not writable.
    """
    if not enabled:
        return None
    folder = config.cache_dir()
    if folder is None:
        return None
    _remove_stale_temporaries(folder)
    return Cache(folder)


#: a temporary file older than this was left by a writer that was killed (a write takes seconds)
STALE_SECONDS = 3600.0


def _remove_stale_temporaries(folder):
    """Remove the temporary files of writers killed midway (older than :data:`STALE_SECONDS`)."""
    now = time.time()
    for tmp in Path(folder).glob(".*.tmp.npz"):
        with contextlib.suppress(OSError):  # another process may remove it first
            if now - tmp.stat().st_mtime > STALE_SECONDS:
                tmp.unlink()


def _check_arrays(arrays, expect):
    """Why ``arrays`` do not match ``expect`` (name -> (shape with None wildcards, dtype kind)), or None."""
    for name, (shape, kind) in expect.items():
        if name not in arrays:
            return f"missing array {name!r}"
        a = arrays[name]
        if a.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, a.shape)):
            return f"array {name!r} has shape {a.shape}, expected {tuple('*' if s is None else s for s in shape)}"
        if a.dtype.kind != kind and not (kind == "f" and a.dtype.kind in "iu"):
            return f"array {name!r} has dtype {a.dtype}, expected kind {kind!r}"
        if a.dtype.kind in "fc" and not np.isfinite(a).all():
            return f"array {name!r} has NaN or infinite entries"
    return None


@dataclasses.dataclass(frozen=True)
class Cache:
    """A cache directory of ``.npz`` entries (see the module docstring).

    Parameters
    ----------
    folder : pathlib.Path
        An existing, writable directory (:func:`open_cache` checks it).
    """

    folder: Path

    def path(self, kind, key):
        """pathlib.Path of the entry ``<kind>-<key>.npz``."""
        return Path(self.folder) / f"{kind}-{key}.npz"

    def load(self, kind, key, expect):
        """Read an entry of arrays written by :meth:`store`.

        Parameters
        ----------
        kind, key : str
        expect : dict of str -> (tuple, str)
            For every array that must be present: its shape (``None`` for any length) and dtype kind
            (``"f"`` float, ``"b"`` bool, ``"i"`` int). Float arrays must be finite.

        Returns
        -------
        (arrays, meta) : (dict of str -> numpy array, dict) or None
            None when there is no entry, or there was a corrupt one (removed with a :class:`CacheWarning`).
        """

        def read(path):
            with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # fh: closed on a bad zip too
                arrays = {k: z[k] for k in z.files}
            if _META not in arrays:  # every entry has one (store writes {} for no metadata)
                raise CorruptEntry("missing its metadata")
            meta = json.loads(str(arrays.pop(_META)))
            if not isinstance(meta, dict):
                raise CorruptEntry(f"metadata is a {type(meta).__name__}, not a dict")
            reason = _check_arrays(arrays, expect)
            if reason is not None:
                raise CorruptEntry(reason)
            return arrays, meta

        return self.load_with(kind, key, read)

    def store(self, kind, key, arrays, meta=None):
        """Write an entry atomically: ``arrays`` (dict of str -> numpy array) and JSON ``meta``.

        Returns
        -------
        pathlib.Path
        """
        arrays = dict(arrays)
        arrays[_META] = np.array(json.dumps({} if meta is None else dict(meta), default=_json_default))

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)

        return self.store_with(kind, key, write)

    def load_with(self, kind, key, read):
        """Read an entry with ``read(path)`` (e.g. ``DefOp.load``).

        ``read`` may raise :class:`CorruptEntry` (or ValueError, OSError, KeyError, ...) for an entry
        that fails its checks; the entry is then removed with a :class:`CacheWarning` (unless another
        process has meanwhile replaced it with a new one).

        Returns
        -------
        object or None
            ``read``'s result; None when there is no entry or it was corrupt.
        """
        path = self.path(kind, key)
        try:
            st = path.stat()
        except FileNotFoundError:
            return None
        if not stat.S_ISREG(st.st_mode):  # e.g. a directory made by hand: not ours to remove
            warnings.warn(f"cache entry {path} is not a regular file; ignored, recomputing", CacheWarning, stacklevel=3)
            return None
        inode = st.st_ino
        try:
            return read(path)
        except _READ_ERRORS as exc:
            reason = str(exc) if isinstance(exc, CorruptEntry) else f"{type(exc).__name__}: {exc}"
            warnings.warn(f"removed corrupt cache entry {path} ({reason}); recomputing it", CacheWarning, stacklevel=3)
            with contextlib.suppress(FileNotFoundError):
                if path.stat().st_ino == inode:  # not a whole entry another process has just renamed into place
                    path.unlink()
            return None

    def remove(self, kind, key):
        """Remove the entry ``<kind>-<key>.npz`` if there is one (an entry another process removed first is fine)."""
        with contextlib.suppress(FileNotFoundError):
            self.path(kind, key).unlink()

    def store_with(self, kind, key, write):
        """Write an entry atomically with ``write(tmp)`` (e.g. ``op.save``), ``tmp`` a temporary path.

        The bytes go to a hidden temporary file in the cache directory, which is renamed into place
        (:func:`os.replace`) once complete; on any error it is removed and the entry left untouched.
        An OSError (the directory became unwritable, the disk is full) only warns: the result the
        caller computed is still returned to the user, just not cached.

        Returns
        -------
        pathlib.Path or None
            None when the entry could not be written.
        """
        path = self.path(kind, key)
        if path.is_dir():  # not ours to replace (see load)
            warnings.warn(f"could not write the cache entry {path} (a directory is in its place); the result is not "
                          "cached", CacheWarning, 2)
            return None
        try:
            opt.write_atomic(path, write)
        except OSError as exc:
            warnings.warn(f"could not write the cache entry {path} ({exc}); the result is not cached", CacheWarning, 2)
            return None
        return path

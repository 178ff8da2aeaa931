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
  10,000 of them, gave 0 loads of wrong data (``tests/test_cache.py`` runs 600); with the digest stamped: 8,952
  rejected, each with a warning, 1,048 harmless (a byte the readers ignore), 0 wrong.
* **Every entry carries the digest of its inputs** (:func:`digest`: its kind and its key, the hash of the mesh,
  the handles in their order, the energy, the solver's settings and :data:`SOLVER_SALT`, the samples Q_k and
  whatever else the caller keyed it on), stamped in the archive's comment when it is written, and checked when it
  is read: an entry of another problem under this one's name (a copied or renamed file, a shared cache
  directory) is removed with a :class:`CacheWarning` naming the file and both digests, and recomputed, never
  used. An entry without a digest (written by an older defop) is stale: recomputed and overwritten, silently.
  Every kind (ground truth ``gt``, operator ``op``, checkpoint ``chunk``, ``branch-minima``, ``traj``) goes
  through :meth:`Cache.store_with` and :meth:`Cache.load_with`, the one place this is done. The stamp also names
  the version that wrote the entry (:data:`VERSION_TAG`), so ``python -m defop cache --prune``
  (:mod:`defop.training.cache_admin`) can tell the entries no version of this code reads.
* **One computation per entry**: two processes sharing the cache (two lessons of the main job side by side) that miss
  the same entry at once do not both compute it: :meth:`Cache.lock` (an ``flock`` on a hidden lock file per entry)
  lets one compute and store while the other waits, then reads the stored entry.

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
import os
import stat
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np

from .. import __version__, config
from .. import options as opt
from ..geometry.archive import Limits, NpzReader
from ..variational.solver import VERSION as _solve_version
from . import cache_files as files
from .cache_files import STAMP, CorruptEntry, read_stamp

__all__ = [
    "Cache",
    "CacheWarning",
    "CorruptEntry",
    "FORMAT",
    "SOLVER_SALT",
    "VERSION_TAG",
    "digest",
    "key",
    "open_cache",
    "read_stamp",
    "solver_settings",
]

#: Version of the algorithm of :mod:`defop.variational.solver` (one number,
#: :data:`defop.variational.solver.VERSION`; bump it there when
#: the solutions change, see the module docstring).
SOLVER_SALT = _solve_version

#: Layout of the cache entries; bump it when the arrays or metadata stored in an entry change.
FORMAT = 1

#: the versions an entry's key was hashed with (:func:`key`), written after its digest in the stamp: an entry with
#: another tag is read by no version of this code (its key differs), and ``cache --prune`` removes it
VERSION_TAG = f"version={__version__};format={FORMAT};solver={SOLVER_SALT}"

_META = "__meta__"  # the entry's JSON metadata, stored as a 0-d string array
#: what an entry read by :meth:`Cache.load` may declare (:class:`defop.geometry.archive.NpzReader`)
ENTRY_LIMITS = Limits(max_members=64, max_array_bytes=4 * 2**30, max_total_bytes=16 * 2**30, max_ndim=6)
#: a damaged .npz can make zipfile/numpy raise nearly anything (BadZipFile, EOFError, NotImplementedError for a
#: flipped compression-method byte, struct.error, zlib.error, SyntaxError in the array header, ...): any failure
#: to read an entry makes it unusable, and it is removed, with a warning naming the file and the exception
_READ_ERRORS = (Exception,)


class CacheWarning(UserWarning):
    """A corrupt cache entry, or one of another problem, was removed (it will be recomputed)."""


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


def digest(kind, key) -> str:
    """The digest an entry of ``kind`` keyed ``key`` carries: the kind and :func:`key`'s hash of its inputs.

    Parameters
    ----------
    kind, key : str

    Returns
    -------
    str
        ``"<kind>-<key>"``.
    """
    return f"{kind}-{key}"


def _stamp(tmp, kind, key):
    """Write entry ``kind``/``key``'s digest and :data:`VERSION_TAG` into the archive comment of the zip ``tmp``."""
    with zipfile.ZipFile(tmp, "a") as zf:
        zf.comment = STAMP + f"{digest(kind, key)} {VERSION_TAG}".encode("ascii")


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
            with NpzReader(path, f"cache entry {path}", "a defop cache entry", ENTRY_LIMITS) as z:
                arrays = z.read_all(z.members())
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
        """Read an entry with ``read(path)`` (e.g. ``DefOp.load``), after checking its digest.

        ``read`` may raise :class:`CorruptEntry` (or ValueError, OSError, KeyError, ...) for an entry
        that fails its checks; the entry is then removed with a :class:`CacheWarning` (unless another
        process has meanwhile replaced it with a new one). So is an entry whose digest is another problem's
        (:func:`digest`); an entry without one is stale and recomputed, without a warning.

        Returns
        -------
        object or None
            ``read``'s result; None when there is no entry or it was corrupt, of another problem or stale.
        """
        path = self.path(kind, key)
        for _ in range(3):  # again if another process renames a new entry into place while this one is read
            try:
                st = path.stat()
            except FileNotFoundError:
                return None
            if not stat.S_ISREG(st.st_mode):  # e.g. a directory made by hand: not ours to remove
                warnings.warn(
                    f"cache entry {path} is not a regular file; ignored, recomputing",
                    CacheWarning,
                    stacklevel=opt.user_stacklevel(),
                )
                return None
            inode = st.st_ino
            try:
                with open(path, "rb") as fh:
                    inode = os.fstat(fh.fileno()).st_ino
                    result = read(path)  # first: its checks say best what is wrong with a damaged entry
                    stamped = files.stamp_of(fh)
                if inode != files.inode(path):
                    continue  # path names another (whole) entry now: the stamp read was not its stamp
            except _READ_ERRORS as exc:
                reason = str(exc) if isinstance(exc, CorruptEntry) else f"{type(exc).__name__}: {exc}"
                return self._discard(path, inode, f"removed corrupt cache entry {path} ({reason}); recomputing it")
            if stamped is None:
                return None  # written by an older defop: stale, recomputed and overwritten
            if stamped not in (f"{digest(kind, key)} {VERSION_TAG}", digest(kind, key)):  # with its tag, or before tags
                return self._discard(
                    path,
                    inode,
                    f"removed cache entry {path}: it holds the result of another problem (digest "
                    f"{stamped.partition(' ')[0]!r}, this problem's is {digest(kind, key)!r}: a copied or renamed "
                    "file, or a shared cache directory); recomputing it",
                )
            files.journal(path, read=True)
            return result
        return None

    @staticmethod
    def _discard(path, inode, message):
        """Warn ``message`` and remove the entry at ``path`` if it is still the file ``inode``; returns None."""
        warnings.warn(message, CacheWarning, stacklevel=opt.user_stacklevel())
        with contextlib.suppress(FileNotFoundError):
            if path.stat().st_ino == inode:  # not a whole entry another process has just renamed into place
                path.unlink()
        return None

    @contextlib.contextmanager
    def lock(self, kind, key):
        """Hold entry ``kind``/``key``'s lock while computing it: another process asking for it waits meanwhile.

        Use it after a miss, and look again inside it (the holder before may have stored the entry). The lock is an
        ``flock`` on the hidden file ``.<kind>-<key>.lock``, released when the holder ends, even when it is killed.
        Where no file lock can be taken (no ``fcntl``, or the lock file cannot be made) nothing is locked and both
        processes compute the same result, stored atomically.
        """
        path = self.lock_path(kind, key)
        fd = files.acquire_lock(path)
        try:
            yield
        finally:
            if fd is not None:
                with contextlib.suppress(OSError):
                    path.unlink()  # first: a waiter that locks this file then sees it is gone and locks a new one
                os.close(fd)

    def lock_path(self, kind, key):
        """pathlib.Path of entry ``kind``/``key``'s lock file (:meth:`lock`)."""
        return Path(self.folder) / f".{kind}-{key}.lock"

    def remove(self, kind, key):
        """Remove the entry ``<kind>-<key>.npz`` if there is one (an entry another process removed first is fine)."""
        with contextlib.suppress(FileNotFoundError):
            self.path(kind, key).unlink()

    def store_with(self, kind, key, write):
        """Write an entry atomically with ``write(tmp)`` (e.g. ``op.save``), ``tmp`` a temporary path.

        ``write`` makes a zip archive (an ``.npz``); its comment then receives the entry's :func:`digest`. The
        bytes go to a hidden temporary file in the cache directory, which is renamed into place
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
            warnings.warn(
                f"could not write the cache entry {path} (a directory is in its place); the result is not cached",
                CacheWarning,
                stacklevel=opt.user_stacklevel(),
            )
            return None

        def stamped(tmp):
            write(tmp)
            _stamp(tmp, kind, key)

        try:
            opt.write_atomic(path, stamped)
        except OSError as exc:
            warnings.warn(
                f"could not write the cache entry {path} ({exc}); the result is not cached",
                CacheWarning,
                stacklevel=opt.user_stacklevel(),
            )
            return None
        files.journal(path)
        return path

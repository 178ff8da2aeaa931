"""Files of the on-disk cache (:mod:`defop.training.cache`) below its entries' contents: the digest stamp in an
entry's archive comment, the per-entry lock files and the journal of the entries a process wrote."""

from __future__ import annotations

import contextlib
import os
import struct

__all__ = ["STAMP", "CorruptEntry", "acquire_lock", "inode", "journal", "read_stamp", "stamp_of"]


class CorruptEntry(ValueError):
    """Raised by a reader given to :meth:`Cache.load_with` for an entry that fails its checks."""


#: the start of the archive comment that carries an entry's digest (:func:`defop.training.cache.digest`)
STAMP = b"defop-cache-digest "
_EOCD = b"PK\x05\x06"  # the zip end-of-central-directory record: 22 bytes, the comment's length in the last 2
_TAIL = 22 + 512  # bytes read from an entry's end to find its stamp (a stamp is well under 512 bytes)


def read_stamp(path):
    """The stamp of the entry file ``path``: ``(digest, version tag)``, each None when absent (an older defop).

    Raises
    ------
    CorruptEntry
        The stamp is damaged (see :func:`stamp_of`).
    OSError
        The file cannot be read.
    """
    with open(path, "rb") as fh:
        stamped = stamp_of(fh)
    if stamped is None:
        return None, None
    digest_, _, tag = stamped.partition(" ")
    return digest_, tag or None


def stamp_of(fh):
    """The digest stamped on an open entry: a str, or None when it has none (written by an older defop).

    Raises
    ------
    CorruptEntry
        The archive's end record is missing, or its comment is not as long as the record says (a truncated or
        damaged stamp), or the comment is not a digest.
    """
    size = fh.seek(0, 2)
    fh.seek(max(0, size - _TAIL))
    tail = fh.read()
    at = tail.rfind(_EOCD)
    if at < 0 or len(tail) < at + 22:
        raise CorruptEntry("no zip end record")
    (n,) = struct.unpack("<H", tail[at + 20 : at + 22])
    comment = tail[at + 22 :]
    if len(comment) != n:
        raise CorruptEntry(f"its end record declares a {n}-byte comment, {len(comment)} bytes follow")
    if n == 0:
        return None
    if not comment.startswith(STAMP):
        raise CorruptEntry(f"its archive comment {comment[:40]!r} is not a defop cache digest")
    return comment[len(STAMP) :].decode("ascii", "replace")


def acquire_lock(path, wait=True):
    """An open descriptor of the lock file ``path`` (a pathlib.Path) holding its exclusive ``flock``, or None.

    ``wait=False``: None at once when another process holds it. None also where no file lock can be taken (no
    ``fcntl``, the file cannot be made). Release it by removing ``path``, then closing the descriptor.
    """
    try:
        import fcntl
    except ImportError:  # no file locks here: no lock
        return None
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
            if os.fstat(fd).st_ino == inode(path):  # still the file at path: the last holder did not remove it
                return fd
        except OSError:
            os.close(fd)
            return None
        os.close(fd)


def journal(path, read=False):
    """Append the entry's file name to the file ``DEFOP_CACHE_LOG`` names, when set: the main job's record of the
    entries a lesson computed (none: the lesson ran from the cache) and, as ``read <name>`` lines (``read=True``),
    of the entries it read (:func:`journal_entries`)."""
    log = os.environ.get("DEFOP_CACHE_LOG", "").strip()
    if log:
        with contextlib.suppress(OSError), open(log, "a") as fh:
            fh.write(("read " if read else "") + path.name + "\n")


def journal_entries(text):
    """(computed, read): the sorted entry names a journal's ``text`` (:func:`journal`) lists as stored and as read."""
    computed, read = set(), set()
    for line in text.splitlines():
        words = line.split()
        if len(words) == 1:
            computed.add(words[0])
        elif len(words) == 2 and words[0] == "read":
            read.add(words[1])
    return sorted(computed), sorted(read)


def inode(path):
    """The inode ``path`` names now, or None when it is gone."""
    try:
        return path.stat().st_ino
    except FileNotFoundError:
        return None

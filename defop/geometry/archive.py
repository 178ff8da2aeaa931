"""The one reader of untrusted ``.npz`` archives: operator files, cache entries and mesh files.

An ``.npz`` is a zip of ``.npy`` arrays. :class:`NpzReader` reads one without pickle and checks it before any
work, in this order, every error a :class:`ArchiveError` (a ValueError) that names the file:

1. the first bytes: a zip archive (a single ``.npy`` array, or anything else, is named as such);
2. the zip directory: at most :attr:`Limits.max_members` members, stored or deflated, unencrypted, and the
   *declared* (uncompressed) size of each member and of all together within the limits (a zip bomb is refused
   here, before any byte is inflated);
3. each member's ``.npy`` header, read from the first bytes of its stream: a plain numeric, bool or string dtype
   (never Python objects, so no pickle), at most :attr:`Limits.max_ndim` dimensions, a byte count within the limit
   and equal to what the member declares (or, with ``exact_size=False``, at most what it holds: reads stop at
   the declared size);
4. then the data, streamed into an array of the declared size: decompression never produces more than the
   member declares, and a damaged stream (bad CRC, truncated) is "damaged or truncated".

Arrays stored big-endian are returned in the machine's byte order (the same values).
"""

from __future__ import annotations

import dataclasses
import io
import math
import struct
import tokenize
import zipfile
import zlib

import numpy as np

__all__ = ["DAMAGED", "ArchiveError", "Limits", "Member", "NpzReader", "Reraise", "size_text"]

#: numpy's own limit on a .npy header: the bytes read from a member's start to parse it
NPY_HEADER_BYTES = 65_536 + 16
#: the longest .npy header text parsed (a huge or deeply nested one is refused, not tokenized)
NPY_HEADER_CHARS = 10_000
#: what a damaged archive can make zipfile, zlib or numpy's header parser raise while it is read
DAMAGED = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    EOFError,
    struct.error,
    NotImplementedError,
    SyntaxError,
    UnicodeError,
    tokenize.TokenError,
    RecursionError,
)


class ArchiveError(ValueError):
    """An ``.npz`` archive that cannot be used; the message names the file and what is wrong with it."""


@dataclasses.dataclass(frozen=True)
class Limits:
    """What an archive may declare before anything is inflated.

    Attributes
    ----------
    max_members : int
        Archive members (arrays).
    max_array_bytes, max_total_bytes : int
        Uncompressed bytes of one array, and of all together.
    max_ndim : int
        Dimensions of an array.
    kinds : str
        numpy dtype kinds allowed (``"biufU"``: bool, integers, floats, strings).
    exact_size : bool
        A member must hold exactly the bytes its header declares (False: at least; reads stop there).
    """

    max_members: int = 16
    max_array_bytes: int = 2 * 2**30
    max_total_bytes: int = 4 * 2**30
    max_ndim: int = 3
    kinds: str = "biufU"
    exact_size: bool = True


@dataclasses.dataclass(frozen=True)
class Member:
    """One array of an archive, from the zip directory and its ``.npy`` header (nothing inflated yet)."""

    name: str
    shape: tuple
    dtype: np.dtype
    fortran: bool
    offset: int
    info: zipfile.ZipInfo


def size_text(n):
    """Bytes in words: ``"32 MiB"``."""
    for unit, factor in (("GiB", 2**30), ("MiB", 2**20), ("kiB", 2**10)):
        if n >= factor:
            return f"{n / factor:.3g} {unit}"
    return f"{n} bytes"


class NpzReader:
    """An ``.npz`` archive opened for checked reading (module docstring); a context manager.

    Parameters
    ----------
    path : pathlib.Path
        A regular file (the caller has checked that it exists and is one).
    label : str
        How errors name the file (``"mesh file m.npz"``, or the path itself).
    what : str
        What the file should be, for "is not ..." (``"a defop operator file"``).
    limits : Limits
    """

    def __init__(self, path, label, what, limits=Limits()):
        self.path, self.label, self.what, self.limits = path, label, what, limits
        self._fh = self._zf = None

    def __enter__(self):
        try:
            self._fh = open(self.path, "rb")
            magic = self._fh.read(6)
            if magic.startswith(b"\x93NUMPY"):
                raise ArchiveError(f"{self.label} is a single .npy array, not {self.what} (an .npz archive)")
            if not magic.startswith((b"PK\x03\x04", b"PK\x05\x06")):
                raise ArchiveError(f"{self.label} is not {self.what} (not a zip archive)")
            self._fh.seek(0)
            with self.translated():
                self._zf = zipfile.ZipFile(self._fh)
        except BaseException:
            self._fh.close() if self._fh is not None else None
            raise
        return self

    def __exit__(self, *exc):
        if self._zf is not None:
            self._zf.close()
        self._fh.close()

    def translated(self):
        """A context turning what a damaged archive raises (:data:`DAMAGED`, OSError) into an ArchiveError."""
        return Reraise((OSError, *DAMAGED, ValueError, MemoryError), self.damaged, keep=(ArchiveError,))

    def damaged(self, exc):
        """The ArchiveError of an exception raised while the archive is read."""
        if isinstance(exc, OSError) and not isinstance(exc, zipfile.BadZipFile):
            return ArchiveError(f"{self.label} cannot be read: {exc}")
        what = self.what.split(" ", 1)[-1]
        return ArchiveError(
            f"{self.label} is not a readable {what}: damaged or truncated ({type(exc).__name__}: {exc})"
        )

    def names(self):
        """The member names as in the zip directory (``"V.npy"``), at most twice the member limit."""
        return [i.filename for i in self._zf.infolist()[: 2 * self.limits.max_members]]

    def members(self, allowed=None, unexpected="unexpected member", check=None):
        """{name: :class:`Member`} of every member (``.npy`` dropped from the name), checked (steps 2-3).

        ``allowed``: the names an archive may hold (None: any); another is refused as ``unexpected``.
        ``check(name, shape, dtype)``: the caller's own check of each header, before the size limits.
        """
        lim = self.limits
        with self.translated():
            infos = self._zf.infolist()
            if len(infos) > lim.max_members:
                raise ArchiveError(f"{self.label} holds {len(infos)} archive members, limit {lim.max_members}")
            out, total = {}, 0
            for info in infos:
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                if (allowed is not None and name not in allowed) or name in out:
                    raise ArchiveError(f"{self.label} is not {self.what}: {unexpected} {info.filename!r}")
                if info.flag_bits & 0x1 or info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                    raise ArchiveError(
                        f"{self.label}: member {info.filename!r} is encrypted or uses an unknown compression"
                    )
                if info.file_size > lim.max_array_bytes + NPY_HEADER_BYTES:
                    raise ArchiveError(
                        f"{self.label}: member {info.filename!r} declares {size_text(info.file_size)} uncompressed, "
                        f"limit {size_text(lim.max_array_bytes)} per array (not inflated)"
                    )
                total += info.file_size
                if total > lim.max_total_bytes:
                    raise ArchiveError(
                        f"{self.label} declares more than {size_text(lim.max_total_bytes)} of arrays in total"
                    )
                out[name] = self._member(info, name, check)
        return out

    def _member(self, info, name, check=None):
        """The :class:`Member` of one zip entry, its .npy header read from the first bytes and checked."""
        with self._zf.open(info) as fh:
            buf = io.BytesIO(fh.read(NPY_HEADER_BYTES))
        fmt = np.lib.format
        try:
            version = fmt.read_magic(buf)
            read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, fortran, dtype = read(buf, max_header_size=NPY_HEADER_CHARS)
        except (ValueError, SyntaxError, TypeError, tokenize.TokenError, RecursionError, MemoryError) as exc:
            # numpy tokenizes the header: "((((" raises tokenize's TokenError, deep nesting a RecursionError
            raise ArchiveError(
                f"{self.label}: member {name} is not a numpy array (a damaged .npy header: {exc})"
            ) from None
        lim = self.limits
        if dtype.hasobject or dtype.kind not in lim.kinds or len(shape) > lim.max_ndim:
            raise ArchiveError(
                f"{self.label}: {name} must hold numbers, got dtype {dtype} with {len(shape)} dimensions; "
                f"{self.what} holds plain numbers (never Python objects or pickles) in at most {lim.max_ndim} "
                "dimensions"
            )
        if check is not None:
            check(name, tuple(shape), dtype)
        nbytes = math.prod(shape) * dtype.itemsize
        dims = "×".join(map(str, shape))
        if nbytes > lim.max_array_bytes:
            raise ArchiveError(
                f"{self.label}: array {name!r} declares a {dims} {dtype} array ({size_text(nbytes)}), "
                f"limit {size_text(lim.max_array_bytes)} per array"
            )
        offset = buf.tell()
        held = info.file_size - offset
        if held != nbytes if lim.exact_size else held < nbytes:
            raise ArchiveError(
                f"{self.label}: {name} is truncated: it declares {dims} {dtype} ({size_text(nbytes)}), but its "
                f"archive member holds {size_text(max(held, 0))} (damaged or truncated)"
            )
        return Member(name, tuple(shape), dtype, fortran, offset, info)

    def read(self, member):
        """The member's data, streamed into an array of the declared (checked) size in the machine's byte order."""
        out = np.empty(member.shape, dtype=member.dtype, order="F" if member.fortran else "C")
        view = memoryview(out.reshape(-1, order="A").view(np.uint8)) if out.size else memoryview(b"")
        with self.translated(), self._zf.open(member.info) as fh:
            fh.read(member.offset)
            got = 0
            while got < len(view):
                chunk = fh.read(min(1 << 22, len(view) - got))
                if not chunk:
                    raise ArchiveError(
                        f"{self.label}: {member.name} is truncated ({got} of {len(view)} bytes): damaged or truncated"
                    )
                view[got : got + len(chunk)] = chunk
                got += len(chunk)
            if self.limits.exact_size:
                fh.read(1)  # the end of the member: zipfile checks its CRC here (BadZipFile if damaged)
        if out.dtype.byteorder not in ("=", "|"):  # big-endian (or explicit little on a big machine): same values
            out = out.astype(out.dtype.newbyteorder("="))
        return out

    def read_all(self, members):
        """{name: array} of ``members`` (a dict of :class:`Member`)."""
        return {name: self.read(m) for name, m in members.items()}


class Reraise:
    """A context that re-raises an exception of ``types`` (but not of ``keep``) as ``make(exc)``, chained."""

    def __init__(self, types, make, keep=()):
        self.types, self.make, self.keep = types, make, keep

    def __enter__(self):
        return self

    def __exit__(self, typ, exc, tb):
        if typ is None or issubclass(typ, self.keep) or not issubclass(typ, self.types):
            return False
        raise self.make(exc) from exc

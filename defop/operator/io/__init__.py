"""Operator files: every kind's save and load, with the checks an untrusted file needs.

**Kinds and formats** (``.npz``, a zip of ``.npy`` arrays, read without pickle; a JSON ``header`` member names the
format). Each kind declares its formats, members and loader (:data:`KINDS`); a loader given another kind's file, a
cache entry or a mesh file names what the file is and which loader reads it.

| kind | format | written by | d | read as |
|---|---|---|---|---|
| ``operator`` | ``defop-operator-1`` | before (★) | 2 | W only; old factors are recomputed |
| ``operator`` | ``defop-operator-2`` | 7c4dc5f | 2 | as saved (d = 2 is implied) |
| ``operator`` | ``defop-operator-3`` | :meth:`DefOp.save` | 2 or 3 (``dim``) | as saved |
| ``branched`` | ``defop-branched-1`` | 0.1 (λ² domains) | 2 or 3 | λ²_b = Ψ_b · l_b as the domain, no box |
| ``branched`` | ``defop-branched-2`` | :meth:`BranchedOperator.save` | 2 or 3 | one DefOp per branch, g_b |
| ``movable`` | ``defop-movable-1`` | :meth:`MovableOp.save` | 2 | the joint TPS and placement |

**Checks before work.** Every error is a ``ValueError`` (:class:`OperatorFileError`) that names the file:

1. the path (missing, a directory, a FIFO) and the kind, from the member names: another kind's file is named;
2. the archive (:class:`defop.geometry.archive.NpzReader`): a zip, at most the kind's member count (16 for a
   single-valued file), known names, declared sizes within :data:`MAX_ARRAY_BYTES` and :data:`MAX_TOTAL_BYTES`
   before anything is inflated, plain dtypes (never objects or pickles), at most 3 dimensions;
3. the JSON header: at most :data:`MAX_HEADER_CHARS` characters and :data:`MAX_JSON_DEPTH` levels, counted before
   it is parsed; its format (another kind's is named), its integer fields checked before any ``int()``
   (:func:`header_int`: ``side: 1.5`` is refused, not read as +1), its objects checked to be objects;
4. the declared shapes against each other, :data:`MAX_CENTERS` and the polynomial degree limit, before an array
   is read;
5. the data, streamed into arrays of the declared size (a damaged stream is "damaged or truncated"), in the
   machine's byte order (big-endian files give the same values);
6. every array's values: float32 or float64 (float16 is refused by name), finite, indices in range, the rest
   pose, the handle columns.

Saves write a temporary file in the target's folder and rename it into place (atomic).
"""

from .branched_file import BRANCH_MEMBERS, BRANCHED_FORMAT, BRANCHED_READS, SHARED_MEMBERS, load_branched, save_branched
from .files import (
    KINDS,
    MAX_ARRAY_BYTES,
    MAX_BRANCHES,
    MAX_CENTERS,
    MAX_HEADER_CHARS,
    MAX_JSON_DEPTH,
    MAX_MEMBERS,
    MAX_TOTAL_BYTES,
    FileKind,
    OperatorFileError,
    header_int,
    json_depth,
    kind_of,
)
from .movable_file import load_movable, save_movable
from .operator_file import FORMAT, FORMAT_VERSION, MEMBERS, READS, load, save

__all__ = [
    "BRANCHED_FORMAT",
    "BRANCHED_READS",
    "BRANCH_MEMBERS",
    "FORMAT",
    "FORMAT_VERSION",
    "KINDS",
    "MAX_ARRAY_BYTES",
    "MAX_BRANCHES",
    "MAX_CENTERS",
    "MAX_HEADER_CHARS",
    "MAX_JSON_DEPTH",
    "MAX_MEMBERS",
    "MAX_TOTAL_BYTES",
    "MEMBERS",
    "READS",
    "SHARED_MEMBERS",
    "FileKind",
    "OperatorFileError",
    "header_int",
    "json_depth",
    "kind_of",
    "load",
    "load_branched",
    "load_movable",
    "save",
    "save_branched",
    "save_movable",
]

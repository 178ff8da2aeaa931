"""Diff two caches of the main job, entry by entry: the same keys, and every array within a tolerance.

A refactor that leaves the solutions unchanged must leave every cached ground truth, operator, trajectory and
branch entry the main job produces unchanged. Run the main job twice, before and after, each with a cache of its
own, then compare::

    DEFOP_CACHE=/tmp/before python -m defop figures --no-record    # on the old commit
    DEFOP_CACHE=/tmp/after  python -m defop figures --no-record    # on the new one
    python benchmarks/compare_cache.py /tmp/before /tmp/after [--tol 1e-12]

Entries are ``<kind>-<key>.npz`` (``defop.training.cache``); the key hashes every input, so a key present on one
side only is an input that changed (or a migration, which this script reports). Arrays are compared by shape,
dtype and values: floats by the largest absolute difference, everything else exactly. The metadata (a JSON dict in
``__meta__``) and JSON headers (an operator file's ``header``) are compared with their timing fields left out, and
arrays named for a clock (``seconds``, ``*_time*``) are skipped. Exits 1 on any difference beyond ``--tol``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

#: metadata fields that are clocks or machine facts, not results
TIMING = ("time", "seconds", "cpu", "wall", "elapsed", "load", "date", "host")


def _entries(folder):
    return {p.name: p for p in Path(folder).glob("*.npz") if not p.name.startswith(".")}


def _read(path):
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = arrays.pop("__meta__", None)
    return arrays, (json.loads(str(meta)) if meta is not None else {})


def _timed(name):
    return any(t in name.lower() for t in TIMING)


def _json(a):
    try:
        return json.loads(str(a))
    except ValueError:
        return str(a)


def _untimed(meta):
    if isinstance(meta, dict):
        return {k: _untimed(v) for k, v in meta.items() if not _timed(k)}
    if isinstance(meta, list):
        return [_untimed(v) for v in meta]
    return meta


def compare_entry(a, b, tol):
    """Differences between two entries, as a list of strings (empty when they agree within ``tol``)."""
    (xa, ma), (xb, mb) = _read(a), _read(b)
    out = []
    if sorted(xa) != sorted(xb):
        out.append(f"arrays {sorted(xa)} != {sorted(xb)}")
    for k in sorted(set(xa) & set(xb)):
        u, v = xa[k], xb[k]
        if _timed(k):
            continue  # a clock (CPU or wall seconds), not a result
        if u.ndim == 0 and u.dtype.kind == "U":  # a JSON header (an operator file's): compared without its clocks
            if _untimed(_json(u)) != _untimed(_json(v)):
                out.append(f"{k}: {_untimed(_json(u))} != {_untimed(_json(v))}")
            continue
        if u.shape != v.shape or u.dtype != v.dtype:
            out.append(f"{k}: {u.dtype}{u.shape} != {v.dtype}{v.shape}")
        elif u.dtype.kind in "fc":
            d = float(np.max(np.abs(u - v))) if u.size else 0.0
            if not d <= tol:
                out.append(f"{k}: max |difference| {d:.3e}")
        elif not np.array_equal(u, v):
            out.append(f"{k}: differs")
    if _untimed(ma) != _untimed(mb):
        out.append(f"metadata differs: {_untimed(ma)} != {_untimed(mb)}")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--tol", type=float, default=1e-12)
    args = ap.parse_args(argv)
    ea, eb = _entries(args.before), _entries(args.after)
    only_a, only_b, both = sorted(set(ea) - set(eb)), sorted(set(eb) - set(ea)), sorted(set(ea) & set(eb))
    bad = 0
    for name in both:
        diffs = compare_entry(ea[name], eb[name], args.tol)
        bad += bool(diffs)
        for d in diffs:
            print(f"DIFF {name}: {d}")
    for name in only_a:
        print(f"ONLY BEFORE {name}")
    for name in only_b:
        print(f"ONLY AFTER  {name}")
    kinds = sorted({n.split("-")[0] for n in both})
    print(
        f"{len(both)} entries in both ({', '.join(kinds)}), {bad} differ beyond {args.tol:g}; "
        f"{len(only_a)} only before, {len(only_b)} only after"
    )
    return 1 if (bad or only_a or only_b) else 0


if __name__ == "__main__":
    sys.exit(main())

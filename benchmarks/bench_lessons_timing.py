"""The lessons' time claims, checked on real clocks: each lesson runs as it is, then its timed claims are judged.

A lesson's checked cells hold no time (nbval runs them with slowed clocks, ``tests/test_lesson_clocks.py``); the
claims about speed that the lessons state live here. Each lesson below runs in a kernel (nbclient, the lesson's
own code and sizes; fast mode when ``DEFOP_FAST=1``), then one cell appended to it judges the lesson's time claims on
the lesson's own variables and prints PASS or FAIL with the measured value:

* ``01_energies``: projected Newton reaches a 1e-8 energy gap at least 5x faster than L-BFGS (wall time);
* ``12_peers``: DefOp's compressed frame at least 30x (fast mode: 10x) faster than 10 libigl ARAP iterations (best
  frame, thread CPU time), on the aleph and the octopus;
* ``14_3d``: every 3D model above 30 frames a second on one core (compressed), and a DefOp frame more than 20x
  faster than 10 libigl ARAP iterations on the bar;
* ``15_branches``: the bar's multi-valued training at most 3x the single-valued training in CPU seconds (run with
  ``DEFOP_CACHE=off``: the cost is measured, not read from the cache).

Frame times come from the lessons' harness (best of the frames, thread CPU time: load adds time, never removes it).
Training times and the frames use the lesson's cache (``DEFOP_CACHE``) unless the claim is about training.
Exit status 1 when a claim fails. Run: ``[DEFOP_FAST=1] python benchmarks/bench_lessons_timing.py [lesson ...]``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"

#: the helper every claim cell starts with: one line per claim, PASS or FAIL, the measured value
CHECK = """
def _check(claim, holds, measured):
    print(f"{'PASS' if holds else 'FAIL'}: {claim} ({measured})")


def _frames(a, b):  # two best frame times and their ratio
    return f"{1e6 * a:.0f} us / {1e6 * b:.1f} us = " + (f"{a / b:.0f}x" if b > 0 else "inf")
"""

#: lesson -> (environment for its kernel, the code that judges its time claims on its own variables)
CLAIMS = {
    "01_energies": (
        {},
        """
_tn, _tl = time_to_gap(newton), time_to_gap(lbfgs)
_check(
    "projected Newton reaches a 1e-8 gap at least 5x faster than L-BFGS",
    _tl >= 5 * _tn,
    f"Newton {_tn:.3f} s, L-BFGS {'not reached in %.1f s' % lbfgs.time if _tl == float('inf') else '%.3f s' % _tl}",
)
""",
    ),
    "12_peers": (
        {},
        """
_bound = dop.config.pick(30, 10)
for _name, _run in runs.items():
    _fast = next(s for s in _run["scores"] if s.name.endswith("compressed"))
    _arap = next(s for s in _run["scores"] if s.name == "libigl ARAP, 10 it.")
    _check(
        f"{_name}: DefOp compressed frame >= {_bound}x faster than 10 ARAP iterations",
        _arap.frame_best >= _bound * _fast.frame_best,
        _frames(_arap.frame_best, _fast.frame_best),
    )
""",
    ),
    "14_3d": (
        {},
        """
for _name, _r in rows.items():
    _check(f"{_name}: above 30 frames a second on one core (compressed)", _r["fps"] > 30, f"{_r['fps']:.0f} FPS")
_arap = by["libigl ARAP, 10 it."]
_check(
    "bar_3d: a DefOp frame is more than 20x faster than 10 ARAP iterations",
    ours.frame_best * 20 < _arap.frame_best,
    _frames(_arap.frame_best, ours.frame_best),
)
""",
    ),
    "15_branches": (
        {"DEFOP_CACHE": "off"},
        """
_check("bar: multi-valued training <= 3x the single-valued (CPU s)", ratio["bar"] <= 3, f"{ratio['bar']:.2f}x")
""",
    ),
}


def judge(stem, timeout=1800):
    """Run one lesson and its claim cell; returns the claim lines (PASS/FAIL) it printed."""
    env, code = CLAIMS[stem]
    nb = nbformat.read(NOTEBOOKS / f"{stem}.ipynb", as_version=4)
    nb.cells.append(nbformat.v4.new_code_cell(CHECK + code))
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        NotebookClient(
            nb, timeout=timeout, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
        ).execute()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    text = "".join(o.get("text", "") for o in nb.cells[-1].outputs if o.get("output_type") == "stream")
    return [line for line in text.splitlines() if line.startswith(("PASS", "FAIL"))]


def main(stems):
    mode = "fast" if os.environ.get("DEFOP_FAST") else "full"
    print(f"lesson time claims, {mode} mode; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    failed = []
    for stem in stems:
        t0 = time.perf_counter()
        lines = judge(stem)
        print(f"\n{stem} ({time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f})")
        print("\n".join("  " + line for line in lines))
        if not lines or any(line.startswith("FAIL") for line in lines):
            failed.append(stem)
    print(f"\nfailed: {failed or 'none'}")
    return not failed


if __name__ == "__main__":
    unknown = [a for a in sys.argv[1:] if a not in CLAIMS]
    if unknown:
        sys.exit(f"unknown lesson(s) {unknown}; known: {', '.join(CLAIMS)}")
    sys.exit(0 if main(sys.argv[1:] or list(CLAIMS)) else 1)

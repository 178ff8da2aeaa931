"""The main job's schedule: which lessons run side by side, and how long the rest will take (pure functions).

The lessons run on ``jobs`` slots (:func:`default_jobs`: one per core). They start longest first, by the seconds
``figures/runtimes.json`` recorded (:func:`expected_seconds`), each on the first slot that frees: the longest lessons
do not end up last beside an idle core (list scheduling, longest processing time first). With two slots on two cores
each lesson's own solves run in its kernel (``DEFOP_N_JOBS=1``, :func:`inner_jobs`), so the two kernels keep the two
cores busy without oversubscribing them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

__all__ = [
    "ALONE",
    "cores",
    "default_jobs",
    "eta",
    "expected_seconds",
    "inner_jobs",
    "makespan",
    "order",
    "overlaps",
    "plan",
]

#: the seconds assumed for a lesson the record does not know
UNKNOWN_SECONDS = 60.0

#: lessons that print times they measure (Table 1's timing rows): they run after the others, one at a time with every
#: core, so that no lesson beside them inflates their times
ALONE = frozenset({"10_timings"})


def plan(names, seconds, jobs):
    """(the lessons in the order they start on ``jobs`` slots, the lessons run after them one at a time).

    One at a time (``jobs == 1``): every lesson in the given (name) order, none after. Side by side: longest first by
    ``seconds`` (:func:`order`), the :data:`ALONE` lessons after the others, longest first too.
    """
    if jobs == 1:
        return list(names), []
    ranked = order(list(names), seconds)
    return [n for n in ranked if n not in ALONE], [n for n in ranked if n in ALONE]


def cores():
    """The cores this process may run on (its affinity where the system tells it, else the machine's)."""
    count = getattr(os, "process_cpu_count", None)  # Python 3.13
    if count is not None:
        return count() or 1
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def default_jobs(n_cores=None):
    """Lessons side by side by default: one per core, at most 2 (every lesson's kernel holds its own memory)."""
    return max(1, min(2, cores() if n_cores is None else n_cores))


def inner_jobs(jobs, n_cores=None):
    """The solver workers inside each lesson (``DEFOP_N_JOBS``) when ``jobs`` lessons run side by side: the cores
    shared out, at least 1; None when one lesson runs at a time (the lesson's own default, every core)."""
    if jobs <= 1:
        return None
    return max(1, (cores() if n_cores is None else n_cores) // jobs)


def expected_seconds(names, record, mode, cold=False):
    """Each lesson's expected seconds from the timing record.

    Parameters
    ----------
    names : list of str
    record : path or dict
        ``figures/runtimes.json`` (a missing file: nothing known) or its contents.
    mode : {"full", "fast"}
    cold : bool
        The times from an empty cache (a clean run) where recorded, else the last run's.

    Returns
    -------
    dict of str -> float
        :data:`UNKNOWN_SECONDS`, or the mean of the known ones, for a lesson never recorded.
    """
    if not isinstance(record, dict):
        record = json.loads(Path(record).read_text()) if record is not None and Path(record).exists() else {}
    known = record.get(mode, {}).get("notebooks", {})
    found = {}
    for name in names:
        entry = known.get(name, {})
        value = entry.get("cold") if cold else None
        value = entry.get("seconds") if value is None else value
        if value is not None:
            found[name] = float(value)
    fallback = sum(found.values()) / len(found) if found else UNKNOWN_SECONDS
    return {name: found.get(name, fallback) for name in names}


def order(names, seconds):
    """``names`` longest first by ``seconds`` (dict), ties in their given order."""
    return sorted(names, key=lambda n: (-seconds[n], names.index(n)))


def makespan(durations, jobs, busy=()):
    """Wall seconds to run ``durations`` in this order on ``jobs`` slots, each on the first slot to free.

    Parameters
    ----------
    durations : sequence of float
    jobs : int
    busy : sequence of float
        Seconds still to go of the lessons running now (one slot each).

    Returns
    -------
    float
    """
    slots = sorted(list(busy) + [0.0] * max(0, jobs - len(busy)))
    for d in durations:
        slots[0] += d
        slots.sort()
    return max(slots) if slots else 0.0


def eta(queued, running, jobs):
    """Seconds until the last lesson ends: ``queued`` expected seconds in order, ``running`` (expected, elapsed)."""
    return makespan(queued, jobs, [max(0.0, e - t) for e, t in running])


def overlaps(spans):
    """For each lesson, the lessons that ran beside it: ``spans`` {name: (start, end)} -> {name: [names]}."""
    return {
        a: sorted(b for b, (s2, e2) in spans.items() if b != a and s2 < e1 and s1 < e2) for a, (s1, e1) in spans.items()
    }

"""The main job's schedule: which lessons run side by side, and how long the rest will take (pure functions).

The lessons run on ``jobs`` slots (:func:`default_jobs`: one per core). They start longest first, by the seconds
``figures/runtimes.json`` recorded (:func:`expected_seconds`), each on the first slot that frees: the longest lessons
do not end up last beside an idle core (list scheduling, longest processing time first). With two slots on two cores
each lesson's own solves run in its kernel (``DEFOP_N_JOBS=1``, :func:`inner_jobs`), so the two kernels keep the two
cores busy without oversubscribing them.

A lesson that read a cache entry another lesson computed in the last run from an empty cache waits for that lesson
to end (:func:`producers`, recorded as ``after``; :func:`next_ready`): beside it, it would only wait on the entry's
lock with its core idle, while another lesson could use that core.
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
    "next_ready",
    "order",
    "overlaps",
    "plan",
    "producers",
    "recorded_after",
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
        The CPU seconds of the lesson in the last whole main job from an empty cache (``cold_job``: the work it
        did there, not the time it waited), else its time from an empty cache of its own (a clean run), where
        recorded; else the last run's.

    Returns
    -------
    dict of str -> float
        :data:`UNKNOWN_SECONDS`, or the mean of the known ones, for a lesson never recorded.
    """
    known = _notebooks(record, mode)
    found = {}
    for name in names:
        entry = known.get(name, {})
        value = entry.get("cold_job", entry.get("cold")) if cold else None
        value = entry.get("seconds") if value is None else value
        if value is not None:
            found[name] = float(value)
    fallback = sum(found.values()) / len(found) if found else UNKNOWN_SECONDS
    return {name: found.get(name, fallback) for name in names}


def _notebooks(record, mode):
    """The record's {name: entry} of ``mode`` (``record``: a path, a missing file or None: nothing known, or a dict)."""
    if not isinstance(record, dict):
        record = json.loads(Path(record).read_text()) if record is not None and Path(record).exists() else {}
    return record.get(mode, {}).get("notebooks", {})


def recorded_after(names, record, mode):
    """{name: the lessons among ``names`` it waits on}: the ``after`` lists the timing record keeps from the last run
    from an empty cache (:func:`producers`)."""
    known = _notebooks(record, mode)
    after = {n: [a for a in known.get(n, {}).get("after", ()) if a in names and a != n] for n in names}
    return {n: a for n, a in after.items() if a}


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


def producers(report):
    """Each lesson's producers in a run from an empty cache: {name: sorted names of the other lessons that computed
    a cache entry it read}, from ``report``'s ``computed`` and ``read`` entry names (lessons with none left out)."""
    made = {}
    for r in report:
        for entry in r.get("computed", ()):
            made.setdefault(entry, r["name"])
    after = {}
    for r in report:
        found = {made[e] for e in r.get("read", ()) if e in made} - {r["name"]}
        if found:
            after[r["name"]] = sorted(found)
    return after


def next_ready(queue, unfinished, after, running):
    """The index in ``queue`` (names, in start order) of the first lesson none of whose ``after`` (dict of name ->
    names) is ``unfinished`` (a set: queued or running); None when every queued lesson waits on one. With nothing
    ``running`` the first queued lesson starts whatever it waits on (a cycle in the record)."""
    for i, name in enumerate(queue):
        if not set(after.get(name, ())) & (set(unfinished) - {name}):
            return i
    return 0 if queue and not running else None

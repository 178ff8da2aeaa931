"""Slowed clocks for every IPython kernel started with ``IPYTHONDIR=tests/slow_clock`` (the nbval run of ``make test``).

Each patched clock of :mod:`time` reports 10x the real time elapsed since its previous call, with a random factor
in [0.7, 1.3] per call (seeded: ``DEFOP_SLOW_CLOCK_SEED``, default 0), so a lesson runs as if on a machine 10x slower
and jittery. The clocks stay monotonic (every step is positive) and start at the real value. A checked output that
changes under them depends on the clock (``tests/test_lesson_clocks.py``).

``time.monotonic`` is left alone: asyncio, tornado and zmq inside the kernel schedule with it (no lesson reads it).
Modules that bound a clock by name before this file ran (the kernel's own machinery) keep the real one; everything
the lesson imports afterwards sees the slowed ones. Worker processes (joblib/loky) start a fresh interpreter without
IPython's startup files: their clocks are real.
"""

import os as _os
import random as _random
import threading as _threading
import time as _time

SLOW_CLOCK_FACTOR = 10.0
SLOW_CLOCK_JITTER = 0.3
#: the clocks patched: (name, ns form) where the ns form returns int nanoseconds
SLOW_CLOCK_NAMES = ("perf_counter", "process_time", "thread_time", "time")


class SlowClock:
    """A clock that advances ``factor`` x (1 ± ``jitter``, uniform per call) as fast as ``real``; monotonic."""

    def __init__(self, real, factor=SLOW_CLOCK_FACTOR, jitter=SLOW_CLOCK_JITTER, rng=None):
        self.real, self.factor, self.jitter = real, float(factor), float(jitter)
        self.rng = rng if rng is not None else _random.Random(0)
        self.lock = _threading.Lock()
        self.last_real = self.value = float(real())

    def __call__(self):
        with self.lock:
            now = float(self.real())
            step = max(now - self.last_real, 0.0)
            self.last_real = now
            self.value += self.factor * step * (1.0 + self.rng.uniform(-self.jitter, self.jitter))
            return self.value

    def ns(self):
        """The same clock in integer nanoseconds (the ``*_ns`` form)."""
        return int(self() * 1e9)


def install(module=_time, seed=None):
    """Replace the clocks of ``module`` (default :mod:`time`) by :class:`SlowClock` s; returns them by name."""
    if getattr(module, "_defop_slow_clocks", None):
        return module._defop_slow_clocks
    seed = int(_os.environ.get("DEFOP_SLOW_CLOCK_SEED", "0")) if seed is None else seed
    clocks = {}
    for i, name in enumerate(SLOW_CLOCK_NAMES):
        clock = SlowClock(getattr(module, name), rng=_random.Random(seed * 1000 + i))
        clock.__name__ = clock.__qualname__ = name
        clocks[name] = clock
        setattr(module, name, clock)
        setattr(module, name + "_ns", clock.ns)
    module._defop_slow_clocks = clocks
    return clocks


try:
    get_ipython  # noqa: B018  (defined in a kernel's startup namespace: install only there)
except NameError:
    pass
else:
    install()
    # the lesson's namespace gets none of this file's names
    del SlowClock, install, SLOW_CLOCK_FACTOR, SLOW_CLOCK_JITTER, SLOW_CLOCK_NAMES, _os, _random, _threading, _time

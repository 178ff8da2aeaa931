"""The slowed clocks of the lessons' nbval run (``tests/slow_clock``) and the rule they enforce.

``make test`` runs every lesson under nbval with ``IPYTHONDIR=tests/slow_clock``: every kernel starts with
``time.perf_counter``, ``process_time``, ``thread_time``, ``time`` and their ``_ns`` forms running 10x slow with
±30% jitter per call, and the stored outputs (made by the main job on real clocks) must still match. These tests
check that the patch is what it claims, that the kernel and joblib's workers live with it, and that no checked
cell of a lesson reads a clock.
"""

from __future__ import annotations

import json
import os
import random
import re
import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SLOW = ROOT / "tests" / "slow_clock"
STARTUP = SLOW / "profile_default" / "startup" / "00-slow-clock.py"
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


class FakeReal:
    """A real clock under the test's control."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def startup():
    """The startup file's names, run outside a kernel (where it installs nothing)."""
    return runpy.run_path(str(STARTUP), run_name="slow_clock_under_test")


def test_outside_a_kernel_the_startup_file_patches_nothing():
    import time

    before = time.perf_counter
    names = startup()
    assert time.perf_counter is before and not hasattr(time, "_defop_slow_clocks")
    assert names["SLOW_CLOCK_FACTOR"] == 10 and names["SLOW_CLOCK_JITTER"] == 0.3


def test_slow_clock_runs_ten_times_slow_with_jitter_and_stays_monotonic():
    names = startup()
    real = FakeReal()
    clock = names["SlowClock"](real, rng=random.Random(5))
    start, values, steps = clock(), [], []
    for _ in range(2000):
        real.now += 0.001
        values.append(clock())
    steps = [b - a for a, b in zip([start, *values], values)]
    ratios = [s / 0.001 for s in steps]
    assert min(ratios) >= 7 - 1e-9 and max(ratios) <= 13 + 1e-9  # 10x, ±30% per call
    assert max(ratios) > 12 and min(ratios) < 8  # the jitter is used, not just allowed
    assert abs((values[-1] - start) / 2.0 - 10) < 0.5  # on average 10x
    assert start == 100.0  # starts at the real value
    real.now -= 1.0  # a real clock stepping back (time.time under NTP) does not make it go back
    assert clock() == values[-1]
    assert isinstance(clock.ns(), int) and clock.ns() >= int(values[-1] * 1e9)


def test_the_same_seed_gives_the_same_clock():
    names = startup()

    def run(seed):
        real = FakeReal()
        clock = names["SlowClock"](real, rng=random.Random(seed))
        out = []
        for _ in range(10):
            real.now += 0.5
            out.append(clock())
        return out

    assert run(3) == run(3) and run(3) != run(4)


def test_install_patches_every_clock_and_its_ns_form_once():
    names = startup()

    class Module:  # a stand-in for the time module
        pass

    module = Module()
    for name in names["SLOW_CLOCK_NAMES"]:
        setattr(module, name, FakeReal())
        setattr(module, name + "_ns", None)
    clocks = names["install"](module, seed=1)
    assert set(clocks) == {"perf_counter", "process_time", "thread_time", "time"}
    for name, clock in clocks.items():
        assert getattr(module, name) is clock and getattr(module, name + "_ns") == clock.ns
    assert names["install"](module, seed=2) is clocks  # a second install changes nothing


KERNEL_CODE = r"""
import asyncio, time
import joblib

def spin(seconds):  # busy real time, measured on the clock left alone
    t = time.monotonic() + seconds
    while time.monotonic() < t:
        pass

clocks = sorted(getattr(time, "_defop_slow_clocks", {}))
m0, p0, c0, w0 = time.monotonic(), time.perf_counter(), time.thread_time(), time.time()
n0 = time.perf_counter_ns()
spin(0.3)
m1, p1, c1, w1 = time.monotonic(), time.perf_counter(), time.thread_time(), time.time()
n1 = time.perf_counter_ns()
steps = []
for _ in range(200):
    a = time.monotonic(); x = time.perf_counter(); spin(0.0005); b = time.monotonic(); y = time.perf_counter()
    steps.append((y - x) / (b - a))
await asyncio.sleep(0.05)  # the kernel's event loop, which runs on time.monotonic
workers = joblib.Parallel(n_jobs=2, backend="loky")(joblib.delayed(pow)(i, 2) for i in range(4))
print(json.dumps({
    "clocks": clocks,
    "perf": (p1 - p0) / (m1 - m0),
    "ns": (n1 - n0) / 1e9 / (m1 - m0),
    "wall": (w1 - w0) / (m1 - m0),
    "cpu": (c1 - c0) / (m1 - m0),
    "steps": steps,
    "workers": workers,
    "leaked": [k for k in ("SlowClock", "install", "SLOW_CLOCK_NAMES") if k in globals()],
}))
"""


def test_a_kernel_started_with_the_slow_clock_ipythondir_runs_ten_times_slow():
    """The real thing: a kernel as nbval starts it (``IPYTHONDIR`` set), its clocks, its event loop, loky workers."""
    jupyter_client = pytest.importorskip("jupyter_client")
    pytest.importorskip("joblib")
    env = {**os.environ, "IPYTHONDIR": str(SLOW)}
    km, kc = jupyter_client.manager.start_new_kernel(kernel_name="python3", env=env)
    try:
        outputs = []

        def collect(msg):
            if msg["msg_type"] == "stream" and msg["content"]["name"] == "stdout":
                outputs.append(msg["content"]["text"])
            if msg["msg_type"] == "error":
                outputs.append("ERROR " + "\n".join(msg["content"]["traceback"]))

        reply = kc.execute_interactive("import json\n" + KERNEL_CODE, timeout=300, output_hook=collect)
        assert reply["content"]["status"] == "ok", outputs
        got = json.loads("".join(outputs))
        # the kernel lives on: a second cell runs and replies
        assert kc.execute_interactive("1 + 1", timeout=60)["content"]["status"] == "ok"
    finally:
        kc.stop_channels()
        km.shutdown_kernel(now=True)
    assert got["clocks"] == ["perf_counter", "process_time", "thread_time", "time"]
    # one interval of 0.3 s read on both clocks: 10x, times one factor in [0.7, 1.3] (the margin: the kernel may be
    # descheduled between the two reads on a loaded machine)
    for key in ("perf", "ns", "wall"):
        assert 6 <= got[key] <= 14, (key, got)
    # CPU time of the busy loop's own thread (the kernel's other threads would add theirs to process_time): at most
    # 10x +30% of the real time
    assert got["cpu"] <= 14
    ratios = sorted(got["steps"])
    inside = [r for r in ratios if 6.9 <= r <= 13.1]
    assert len(inside) >= 0.8 * len(ratios), ratios  # 200 short steps: 10x ±30% (a few descheduled reads aside)
    assert inside[0] < 8 and inside[-1] > 12 and 9 < inside[len(inside) // 2] < 11, inside  # the jitter is there
    assert got["workers"] == [0, 1, 4, 9]
    assert got["leaked"] == []


def checked_cells():
    """Every checked cell's code, with the code of the cells that define a function it calls."""
    for path in NOTEBOOKS:
        cells = ["".join(c["source"]) for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
        defined = {name: src for src in cells for name in re.findall(r"^def (\w+)\(", src, re.MULTILINE)}
        for i, src in enumerate(cells):
            if "NBVAL_CHECK_OUTPUT" in src:
                used = [defined[n] for n in defined if re.search(rf"\b{n}\(", src) and defined[n] != src]
                yield pytest.param(path.stem, i, "\n".join([src, *used]), id=f"{path.stem}-code{i}")


#: a clock read or a time/FPS value in a checked cell's code
CLOCK = re.compile(
    r"perf_counter|process_time|thread_time|time\.time|timeit|time\.monotonic|time_history|\bfps\b|frame_best|"
    r"frame_median|_seconds\b|\.seconds\b|train_time|stage_times|eval_time|gt_time|preprocess_s|\bcost=",
    re.IGNORECASE,
)


@pytest.mark.parametrize("stem,index,src", list(checked_cells()))
def test_no_checked_cell_reads_a_clock(stem, index, src):
    """A checked cell is compared by nbval on every run: a time in it makes a timed test (the clock decides)."""
    hits = sorted({m.group(0) for m in CLOCK.finditer(src)})
    assert not hits, (
        f"{stem} (code cell {index}, with the functions it calls) reads a clock or a time ({hits}): "
        "print it in an unchecked cell"
    )


def test_make_test_runs_the_lessons_with_the_slowed_clocks():
    """The nbval run of ``make test`` is the slowed-clock run: its kernels start with this IPYTHONDIR."""
    make = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^test:.*\n((?:\t.*\n)+)", make, re.MULTILINE)
    assert recipe, "Makefile has no test recipe"
    nbval = [line for line in recipe[1].splitlines() if "$(NBVAL)" in line]
    assert nbval and all("IPYTHONDIR=$(CURDIR)/tests/slow_clock" in line for line in nbval), nbval
    assert STARTUP.is_file()

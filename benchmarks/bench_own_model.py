"""Your own model, from an empty cache at default settings: three journeys, each against its target.

The journeys call the library as a user does (a ``from_*`` constructor, then ``dop.train`` with its defaults):

* **star**: a five-pointed star outline (``dop.shapes.from_polygon``), its 5 tips moving, its centre fixed;
* **glyph**: an "&" rendered by matplotlib to a greyscale picture (``dop.shapes.from_image``, automatic handles);
* **torus**: a torus written as a binary STL (``dop.shapes.from_surface`` from the path, about 2,000 tetrahedral
  vertices by default), a patch of 4 moving handles in its tube on one side and 4 fixed ones on the other; with
  ``bar_3d`` too (``--bar``), the catalogue's beam with its moving end patch.

Each is timed from an empty cache (a fresh ``DEFOP_CACHE`` per journey) and fresh solver processes: wall and CPU
seconds of the constructor and the training (CPU summed over the solver processes, the training's own stage times),
and the peak resident memory (``VmHWM``) of this process (over the journeys run so far: run one journey per
invocation for its own) and of the largest solver process (fresh per journey). Then the held-out
error: the RMS vertex distance to the verified ground truth over all held-out poses and vertices, relative to the
bounding-box diagonal (and the worst pose's), over ``N_TEST`` held-out poses (2D:
``dop.training.held_out`` from the shape's regions; 3D: the fixed distribution of exact rigid patch motions at the
default region size, ``rigid_patch_samples(..., jitter=0)``, seed 1000), each solved from the rest pose and from the
operator's prediction, the lowest verified minimum kept. The held-out solves are not part of the journey's time.

Targets: every journey at most 5 minutes wall on 2 idle cores; the 3D journeys at most 2% RMS of the diagonal.
The load average is printed beside the times: on a shared machine wall seconds grow with it, CPU seconds much less.
Run: ``python benchmarks/bench_own_model.py [star] [glyph] [torus] [bar_3d]`` (default: the three journeys;
``--bar`` adds bar_3d).
"""

from __future__ import annotations

import os
import struct
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import defop as dop
from defop.geometry.volumetric.examples import torus_surface
from defop.scene.handles import patches
from defop.training.sampling import rigid_patch_samples

N_TEST = 20
WALL_TARGET = 300.0
RMS_TARGET_3D = 0.02


def star_outline(k=5, outer=1.0, inner=0.45):
    a = np.pi / 2 + np.arange(2 * k) * np.pi / k
    r = np.where(np.arange(2 * k) % 2 == 0, outer, inner)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def glyph_picture(char="&", pixels=400):
    """A greyscale picture (pixels, pixels) in [0, 1] of ``char`` in black on white (matplotlib's DejaVu Sans)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(4, 4), dpi=pixels / 4)
    fig.text(0.5, 0.5, char, fontsize=200, ha="center", va="center")
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba(), float) / 255
    plt.close(fig)
    return rgba[..., :3].mean(axis=-1)


def write_stl(path, V, F):
    """A binary STL (float32 corners, as CAD tools write it)."""
    rec = b"".join(struct.pack("<3f", 0, 0, 0) + V[t].astype("<f4").tobytes() + b"\0\0" for t in F)
    Path(path).write_bytes(b" " * 80 + struct.pack("<I", len(F)) + rec)
    return Path(path)


def torus_handles():
    """4 moving handles in the tube at x = 1 (a square of side 0.3 across it) and the 4 mirrored at x = -1, fixed."""
    square = np.array([[1, 0, 1], [1, 0, -1], [-1, 0, -1], [-1, 0, 1]]) * 0.15
    return np.vstack([square + [1.0, 0, 0], -square - [1.0, 0, 0]]), np.array([True] * 4 + [False] * 4)


def journeys(folder):
    """name -> constructor (no arguments) of each journey's shape."""
    star = star_outline()
    H, moving = torus_handles()
    picture = glyph_picture()
    return {
        "star": lambda: dop.shapes.from_polygon(
            star, handles=np.vstack([0.85 * star[::2], [[0.0, 0.0]]]), moving=[True] * 5 + [False], name="star"
        ),
        "glyph": lambda: dop.shapes.from_image(picture, name="glyph"),
        "torus": lambda: dop.shapes.from_surface(
            write_stl(folder / "torus.stl", *torus_surface()), handles=H, moving=moving, name="torus"
        ),
        "bar_3d": lambda: dop.shapes.load("bar_3d"),
    }


def test_poses(shape):
    """The held-out configurations: 2D from the shape's regions (None: ``held_out`` draws them), 3D exact rigid
    patch motions at the default region size (the fixed distribution)."""
    if shape.mesh.dim == 2:
        return None
    return rigid_patch_samples(patches(shape), N_TEST, np.random.default_rng(1000), jitter=0, regions=shape.regions)


def held_out_rms(shape, op):
    """(RMS / diagonal per held-out pose, converged flags)."""
    Q = test_poses(shape)
    Q, X, ok = dop.training.held_out(shape, "sarap", N_TEST, 1000, like=op, progress=False, samples=Q)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.defop.ExtrapolationWarning)
        pred = op(Q)
    return np.sqrt(np.mean(np.sum((pred - X) ** 2, axis=-1), axis=1)) / shape.mesh.bbox_diagonal, ok


def peak_mb(pid="self"):
    """Peak resident memory of a process, MB (Linux ``VmHWM``; 0 where it cannot be read)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def fresh_workers():
    """Shut joblib's reusable worker processes down, so the next journey's peak memory is its own."""
    from joblib.externals.loky import get_reusable_executor

    get_reusable_executor().shutdown(wait=True)


def worker_peak_mb():
    import psutil

    return max([peak_mb(p.pid) for p in psutil.Process().children(recursive=True)] or [0.0])


def run(name, make):
    fresh_workers()
    with tempfile.TemporaryDirectory() as cache:
        os.environ["DEFOP_CACHE"] = cache  # an empty cache for this journey
        load0 = os.getloadavg()[0]
        w0, c0 = time.perf_counter(), time.process_time()
        shape = make()
        w_shape, c_shape = time.perf_counter() - w0, time.process_time() - c0
        op, rec = dop.train(shape)
        wall = time.perf_counter() - w0
        cpu = c_shape + sum(rec.stage_times.values())
        load1 = os.getloadavg()[0]
        own, kids = peak_mb(), worker_peak_mb()
        rms, ok = held_out_rms(shape, op)
    total = float(np.sqrt(np.mean(rms**2)))
    d = shape.mesh.dim
    p = rec.params
    print(
        f"{name:7s} {d}D {shape.mesh.n_vertices:6d} vertices, m = {p['m']}, rounds = {p['rounds']}, sampling "
        f"{p['sampling']}: wall {wall:6.1f} s (shape {w_shape:.1f} s), CPU {cpu:6.1f} s, peak memory {own:.0f} MB "
        f"(largest solver process {kids:.0f} MB); load average {load0:.1f} -> {load1:.1f}"
    )
    rms_ok = d == 2 or total <= RMS_TARGET_3D
    print(
        f"        held-out RMS / diagonal over {len(rms)} poses ({int(ok.sum())} converged): "
        f"{100 * total:.2f}%, worst pose {100 * rms.max():.2f}%"
        + ("" if d == 2 else f" [target <= {100 * RMS_TARGET_3D:.0f}%: {'met' if rms_ok else 'MISSED'}]")
        + f"; wall [target <= {WALL_TARGET:.0f} s: {'met' if wall <= WALL_TARGET else 'MISSED'}]",
        flush=True,
    )
    return wall, cpu, total


def main(argv):
    names = [a for a in argv if not a.startswith("-")] or ["star", "glyph", "torus"]
    if "--bar" in argv:
        names.append("bar_3d")
    print(f"bench_own_model: {os.cpu_count()} cores, load average {os.getloadavg()}, defop {dop.__version__}")
    with tempfile.TemporaryDirectory() as folder:
        makers = journeys(Path(folder))
        for name in names:
            run(name, makers[name])


if __name__ == "__main__":
    main(sys.argv[1:])

"""Bistable shapes nobody tuned for: a seeded generator of strips that buckle, and their acceptance.

:func:`random_case` draws, from one seed, a strip about 1 long (a bar, Fig. 10's kind of bistable shape) with

* its **aspect ratio**: width ∈ [0.12, 0.28], the right end narrowed by a factor ∈ [0.7, 1];
* **holes** (seeds ≡ 1 or 3 mod 4: half the seeds): one or two discs of radius ∈ [0.2, 0.32] × the width, at
  x ∈ [0.25, 0.75], off the centre line by up to 0.1 × the width;
* **asymmetric supports** (seeds ≡ 2 or 3 mod 4: half the seeds): two or three fixed handles anywhere in
  x ∈ [0.02, 0.12] at random heights, and the moving handle at a random height (else three fixed handles on
  the left end at 15, 50, 85 % of its width and the moving one on the right end's centre line);
* a **slanted out-and-back path** (every seed): the moving handle pushed in by dx ∈ [0.1, 0.2] and dragged across
  from q_y − p_y = −a to +a (a ∈ [0.22, 0.29]) while dx changes by a slant s ∈ ±[0.02, 0.1], 100 steps there and
  100 back.

:func:`accept` keeps a case only when the solver's warm-started continuation along the path verifies at every frame
and jumps exactly twice, once on the way out and once on the way back (the hysteresis loop of Fig. 10);
``follow`` plays no part. The mesh is small (``VERTICES``) so that many cases run on a busy machine.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..analysis import branches as ab
from ..scene import shapes

__all__ = ["RandomCase", "VERTICES", "accept", "random_case", "random_cases", "run_random"]

#: mesh vertices of a random case (about)
VERTICES = 250
#: steps of the path one way
STEPS = 100


@dataclasses.dataclass
class RandomCase:
    """One drawn case: its seed, the shape (one moving handle), the path's two ends and what was drawn."""

    seed: int
    shape: object
    path: tuple
    drawn: dict


def _strip(rng, width, holes):
    taper = rng.uniform(0.7, 1.0)
    outer = np.array([[0, 0], [1, 0.5 * width * (1 - taper)], [1, 0.5 * width * (1 + taper)], [0, width]], float)
    out = []
    for x in sorted(rng.uniform(0.25, 0.75, size=holes)):
        if out and x - out[-1][0] < 0.2:
            continue  # keep holes apart
        h = width * (1 - (1 - taper) * x)  # local width (the strip narrows to the right)
        r = rng.uniform(0.2, 0.32) * h
        y = 0.5 * width + rng.uniform(-0.1, 0.1) * h
        out.append((x, y, r))
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    return outer, [np.stack([x + r * np.cos(t), y + r * np.sin(t)], axis=1) for x, y, r in out], taper


def random_case(seed, vertices=VERTICES):
    """The case of one seed (module docstring): a :class:`RandomCase`."""
    rng = np.random.default_rng(seed)
    holes = 0 if seed % 4 in (0, 2) else int(rng.integers(1, 3))
    asymmetric = seed % 4 in (2, 3)
    width = rng.uniform(0.12, 0.28)
    outer, hole_polys, taper = _strip(rng, width, holes)
    right = 0.5 * width * (1 - taper), 0.5 * width * (1 + taper)
    if asymmetric:
        k = int(rng.integers(2, 4))
        fixed = np.stack([rng.uniform(0.02, 0.12, k), width * rng.uniform(0.1, 0.9, k)], axis=1)
        y_m = right[0] + (right[1] - right[0]) * rng.uniform(0.3, 0.7)
    else:
        fixed = np.array([[0.02, 0.15 * width], [0.02, 0.5 * width], [0.02, 0.85 * width]])
        y_m = 0.5 * width
    handles = np.vstack([[[0.96, y_m]], fixed])
    moving = np.zeros(len(handles), bool)
    moving[0] = True
    shape = shapes.from_polygon(
        outer,
        hole_polys,
        handles,
        moving,
        n_vertices=vertices,
        name=f"random_{seed}",
        description="a random strip with holes and supports",
    )
    dx, a = -float(rng.uniform(0.1, 0.2)), float(rng.uniform(0.22, 0.29))
    s = float(rng.choice([-1, 1]) * rng.uniform(0.02, 0.1))
    path = ((dx - s / 2, -a), (dx + s / 2, a))
    drawn = {"width": float(width), "taper": float(taper), "holes": len(hole_polys), "asymmetric": asymmetric}
    drawn.update(push=-dx, half_height=a, slant=s)
    return RandomCase(seed, shape, path, drawn)


def accept(case, energy="sarap", steps=STEPS):
    """(accepted, reason, truth): the solver's continuation along the case's path of ``steps`` steps each way
    (``truth`` = X, E, converged of :func:`defop.analysis.branches.solver_path`), accepted when every frame
    verifies and it jumps exactly twice, once each way."""
    Qs = ab.path_of(case.shape, 0, case.path, steps)
    X, E, ok = ab.solver_path(case.shape, Qs, energy)
    if not ok.all():
        return False, f"{int((~ok).sum())} of {len(ok)} continuation frames did not verify", (X, E, ok)
    js = ab.jump_frames(X, case.shape.mesh.bbox_diagonal)
    if len(js) != 2 or not (js[0] <= steps < js[1]):
        return False, f"the solver jumps {len(js)} times (frames {js.tolist()}), not once each way", (X, E, ok)
    return True, f"the solver jumps at frames {js.tolist()}", (X, E, ok)


def random_cases(n, max_seeds=None, energy="sarap", log=print, vertices=VERTICES, steps=STEPS, first=0):
    """The first ``n`` accepted cases from seeds ``first``, ``first`` + 1, …: a list of (RandomCase, truth); ``log``
    gets one line per seed (accepted or rejected, with the reason). Stops after ``max_seeds`` seeds (default 5 n).
    ``vertices`` and ``steps``: the mesh size and the path's steps each way."""
    out, seed = [], first
    max_seeds = 5 * n if max_seeds is None else max_seeds
    while len(out) < n and seed < first + max_seeds:
        try:
            case = random_case(seed, vertices)
        except ValueError as exc:  # a mesh that cannot be made (reported, not fatal)
            log(f"seed {seed}: rejected: {exc}")
            seed += 1
            continue
        ok, reason, truth = accept(case, energy, steps)
        log(f"seed {seed}: {'accepted' if ok else 'rejected'}: {reason}; drawn {_fmt(case.drawn)}")
        if ok:
            out.append((case, truth))
        seed += 1
    return out


def _fmt(drawn):
    return ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in drawn.items())


def run_random(case, truth, energy="sarap", n=None, steps=STEPS):
    """Build (:func:`defop.analysis.branches.build`, :data:`defop.analysis.branches.PARAMS`; ``n`` samples per side)
    and compare a random case along its path (``truth``: :func:`accept`'s, for ``steps`` steps each way): a
    :class:`defop.analysis.branches.Case`."""
    minima, branches, bop, single, fit_seconds = ab.build(case.shape, 0, case.path, n, energy)
    Qs = ab.path_of(case.shape, 0, case.path, steps)
    c = ab.compare(case.shape, bop, single, Qs, energy, truth=truth)
    return ab.Case(case.shape.name, case.shape, minima, branches, bop, single, c, fit_seconds)

"""Sampling regions of the moving handles (§3.3): where the training configurations Q_k are drawn.

Each region is a small immutable class, centred at its handle's rest position p_l, that can
validate its parameters (on construction), ``sample`` m points with an explicit ``rng``, and give
its ``outlines`` for drawing. :func:`as_region` turns the dict form used in older code and notebooks
(``{"kind": "disc", "radius": 0.2}``) into a region; ``region["kind"]`` still works on a region.

The dimension d is read from the centre (2 or 3). ``ball``, ``gaussian``, ``voronoi`` and ``mixture`` work
in any dimension; ``disc``, ``ellipse`` and ``circle`` are 2D names (a ball in 2D is a disc, and draws the
same points).

========  ==========================================  ============================================
kind      class                                        sample
========  ==========================================  ============================================
ball      :class:`Ball` (radius)                       uniform in a ball of R^d
disc      :class:`Disc` (radius)                       uniform in a disc (2D)
ellipse   :class:`Ellipse` (axes a_x, a_y)             uniform in an axis-aligned ellipse
circle    :class:`Circle` (radius)                     uniform on a circle
gaussian  :class:`Gaussian` (sigma)                    isotropic normal
voronoi   :class:`Voronoi` (radius)                    uniform in p_l's Voronoi cell among the moving
                                                       handles, clipped to a ball (Fig. 1)
mixture   :class:`Mixture` (components, weights)       each point from a component drawn by weight
========  ==========================================  ============================================
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import options as opt

REGION_KINDS = ("disc", "ball", "ellipse", "circle", "gaussian", "voronoi", "mixture")


def _positive(value, what):
    try:
        return opt.positive("", value)
    except ValueError:
        raise ValueError(what.format(value=value)) from None


def _unit_circle(n):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([np.cos(t), np.sin(t)])


def _disc(rng, k, radius):
    r = radius * np.sqrt(rng.uniform(size=k))
    t = rng.uniform(0, 2 * np.pi, size=k)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def _ball(rng, k, radius, d):
    """k points uniform in the ball of ``radius`` in R^d: in 2D the disc's draws (:func:`_disc`); else a normal
    direction and a radius r·u^{1/d}."""
    if d == 2:
        return _disc(rng, k, radius)
    u = rng.normal(size=(k, d))
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    return u * (radius * rng.uniform(size=k) ** (1.0 / d))[:, None]


class Region:
    """Base class: a sampling region around one moving handle."""

    kind = ""
    dims = (2, 3)  # the dimensions the region is defined in
    positive_fields = ()  # the fields that must be positive numbers, checked on construction

    def __post_init__(self):
        for name in self.positive_fields:
            what = f"{self.kind} needs a positive {name!r}, got {{value!r}}"
            object.__setattr__(self, name, _positive(getattr(self, name), what))

    def sample(self, rng, center, m, P=None, index=None):
        """m points of the region around ``center``.

        Parameters
        ----------
        rng : numpy.random.Generator
        center : (d,) numpy array
            The handle's rest position p_l; d = 2 or 3.
        m : int
        P : (n,d) numpy array, optional
            All moving handles' rest positions (used by :class:`Voronoi`).
        index : int, optional
            Row of this handle in ``P``.

        Returns
        -------
        points : (m,d) numpy array

        Raises
        ------
        ValueError
            A centre of another dimension than the region's (``disc`` in 3D: use ``ball``).
        """
        c = np.asarray(center, float)
        self.check_dim(c.shape[-1] if c.ndim == 1 else -1)
        return c + self._offsets(rng, int(m), c, P, index)

    def check_dim(self, d):
        """Raise ValueError unless the region is defined in dimension d."""
        if d not in self.dims:
            hint = "; use {'kind': 'ball', 'radius': r} in 3D" if self.dims == (2,) else ""
            raise ValueError(f"a {self.kind} region is defined in {' or '.join(map(str, self.dims))}D, not {d}D{hint}")

    def outlines(self, center, P=None, index=None, n=96):
        """Closed outlines for drawing: list of ((k,2) numpy array, line style ``"-"``, ``"--"`` or ``":"``)."""
        raise NotImplementedError

    def to_dict(self):
        """The dict form, e.g. ``{"kind": "disc", "radius": 0.2}``."""
        d = {"kind": self.kind}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            d[f.name] = [c.to_dict() for c in v] if f.name == "components" else (list(v) if isinstance(v, tuple) else v)
        return d

    def __getitem__(self, key):
        """Dict-style read access (``region["kind"]``, ``region["radius"]``), as for the old dict regions."""
        return self.to_dict()[key]


@dataclasses.dataclass(frozen=True)
class Ball(Region):
    """Uniform in a ball of ``radius`` around p_l, in any dimension (in 2D the same points as :class:`Disc`)."""

    radius: float
    kind = "ball"
    positive_fields = ("radius",)

    def _offsets(self, rng, m, c, P, index):
        return _ball(rng, m, self.radius, len(c))

    def outlines(self, center, P=None, index=None, n=96):
        """The circle in 2D; in 3D the ball's three great circles in the coordinate planes, (n,3) each."""
        c = np.asarray(center, float)
        if len(c) == 2:
            return [(c + self.radius * _unit_circle(n), "-")]
        circle = self.radius * _unit_circle(n)
        planes = [(0, 1), (1, 2), (0, 2)]
        return [(c + np.insert(circle, 3 - sum(p), 0.0, axis=1), "-") for p in planes]


@dataclasses.dataclass(frozen=True)
class Disc(Ball):
    """Uniform in a disc of ``radius`` around p_l (the 2D name of :class:`Ball`)."""

    kind = "disc"
    dims = (2,)


@dataclasses.dataclass(frozen=True)
class Ellipse(Region):
    """Uniform in an axis-aligned ellipse with semi-axes ``axes = (a_x, a_y)`` around p_l."""

    axes: tuple
    kind = "ellipse"
    dims = (2,)

    def __post_init__(self):
        try:
            ax = np.asarray(self.axes, float)
        except (TypeError, ValueError):
            ax = np.zeros(0)
        if ax.shape != (2,) or not np.all(np.isfinite(ax)) or np.any(ax <= 0):
            raise ValueError(f"ellipse needs two positive 'axes' [a_x, a_y], got {self.axes!r}")
        object.__setattr__(self, "axes", (float(ax[0]), float(ax[1])))

    def _offsets(self, rng, m, c, P, index):
        return _disc(rng, m, 1.0) * np.asarray(self.axes, float)

    def outlines(self, center, P=None, index=None, n=96):
        return [(np.asarray(center, float) + _unit_circle(n) * np.asarray(self.axes), "-")]


@dataclasses.dataclass(frozen=True)
class Circle(Region):
    """Uniform on a circle of ``radius`` around p_l."""

    radius: float
    kind = "circle"
    dims = (2,)
    positive_fields = ("radius",)

    def _offsets(self, rng, m, c, P, index):
        t = rng.uniform(0, 2 * np.pi, size=m)
        return self.radius * np.column_stack([np.cos(t), np.sin(t)])

    def outlines(self, center, P=None, index=None, n=96):
        return [(np.asarray(center, float) + self.radius * _unit_circle(n), "--")]


@dataclasses.dataclass(frozen=True)
class Gaussian(Region):
    """Isotropic normal with standard deviation ``sigma`` around p_l."""

    sigma: float
    kind = "gaussian"
    positive_fields = ("sigma",)

    def _offsets(self, rng, m, c, P, index):
        return rng.normal(scale=self.sigma, size=(m, len(c)))

    def outlines(self, center, P=None, index=None, n=96):
        c = np.asarray(center, float)
        return [(c + self.sigma * _unit_circle(n), "--"), (c + 2 * self.sigma * _unit_circle(n), ":")]


@dataclasses.dataclass(frozen=True)
class Voronoi(Region):
    """Uniform in p_l's Voronoi cell among the moving handles, clipped to a disc of ``radius``."""

    radius: float
    kind = "voronoi"
    positive_fields = ("radius",)

    def _offsets(self, rng, m, c, P, index):
        others = np.delete(np.asarray(P, float), index, axis=0) if P is not None else np.zeros((0, len(c)))
        out = np.empty((0, len(c)))
        for _ in range(1000):  # rejection sampling from the ball
            cand = _ball(rng, max(2 * (m - len(out)), 16), self.radius, len(c))
            if len(others):
                pts = c + cand  # the test on absolute positions, as the samples are returned
                d_own = np.sum((pts - c) ** 2, axis=1)
                d_other = np.min(np.sum((pts[:, None] - others[None]) ** 2, axis=-1), axis=1)
                cand = cand[d_own <= d_other]
            out = np.vstack([out, cand])
            if len(out) >= m:
                return out[:m]
        raise ValueError(f"the Voronoi region of handle {index} is too small to sample")

    def outlines(self, center, P=None, index=None, n=96):
        c = np.asarray(center, float)
        poly = c + self.radius * _unit_circle(n)
        if P is not None and index is not None:
            for j, q in enumerate(np.asarray(P, float)):
                if j != index and not np.allclose(q, c):
                    poly = _clip_halfplane(poly, c, q)
        return [(poly, "-")]


@dataclasses.dataclass(frozen=True)
class Mixture(Region):
    """Each point from one of ``components``, drawn with probability proportional to ``weights``."""

    components: tuple
    weights: tuple
    kind = "mixture"

    def __post_init__(self):
        comps, w = self.components, self.weights
        try:
            w = np.asarray(w, float).ravel()
        except (TypeError, ValueError):
            w = np.zeros(0)
        if not comps or len(w) != len(comps) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError("mixture needs components and as many non-negative weights (not all zero)")
        object.__setattr__(self, "components", tuple(as_region(c, f"component {i}") for i, c in enumerate(comps)))
        object.__setattr__(self, "weights", tuple(float(x) for x in w))

    def _offsets(self, rng, m, c, P, index):
        w = np.asarray(self.weights)
        for sub in self.components:
            sub.check_dim(len(c))
        comp = rng.choice(len(w), size=m, p=w / w.sum())
        out = np.empty((m, len(c)))
        for j, sub in enumerate(self.components):
            sel = np.flatnonzero(comp == j)
            if len(sel):
                out[sel] = sub._offsets(rng, len(sel), c, P, index)
        return out

    def outlines(self, center, P=None, index=None, n=96):
        return [o for comp in self.components for o in comp.outlines(center, P, index, n)]


_CLASSES = {cls.kind: cls for cls in (Disc, Ball, Ellipse, Circle, Gaussian, Voronoi, Mixture)}


def as_region(spec, name="region"):
    """A :class:`Region` from a region or its dict form; ValueError naming ``name`` if it is invalid.

    Parameters
    ----------
    spec : Region or dict
        E.g. ``{"kind": "disc", "radius": 0.2}`` or
        ``{"kind": "mixture", "components": [...], "weights": [...]}``.
    name : str
        Used in messages ("region 3").

    Returns
    -------
    region : Region
    """
    if isinstance(spec, Region):
        return spec
    if not isinstance(spec, dict) or "kind" not in spec:
        raise ValueError(f"{name} must be a Region or a dict with a 'kind' in {REGION_KINDS}, got {spec!r}")
    kind = spec["kind"]
    if kind not in _CLASSES:
        raise ValueError(f"{name} has unknown kind {kind!r}; known kinds: {', '.join(REGION_KINDS)}")
    cls = _CLASSES[kind]
    params = {f.name: spec.get(f.name) for f in dataclasses.fields(cls)}
    extra = set(spec) - set(params) - {"kind"}
    if extra:
        raise ValueError(f"{name} ({kind}) has unknown parameter(s) {sorted(extra)}; expected {sorted(params)}")
    try:
        return cls(**params)
    except ValueError as e:
        raise ValueError(f"{name} ({kind}): {e}") from None


def check_region(spec, name="region"):
    """Validate a region (or its dict form); raise ValueError naming the problem."""
    as_region(spec, name)


def _clip_halfplane(poly, p, q):
    """Clip a polygon to the half-plane of points closer to p than to q (Sutherland-Hodgman)."""
    nx, ny = q[0] - p[0], q[1] - p[1]
    off = nx * (p[0] + q[0]) / 2 + ny * (p[1] + q[1]) / 2
    side = poly[:, 0] * nx + poly[:, 1] * ny
    inside = side <= off
    out = []
    for i in range(len(poly)):
        k = (i + 1) % len(poly)
        a, b = poly[i], poly[k]
        if inside[i]:
            out.append(a)
        if inside[i] != inside[k]:
            s = (off - side[i]) / (side[k] - side[i])
            out.append(a + s * (b - a))
    return np.array(out) if out else poly[:0]

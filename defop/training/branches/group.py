"""Grouping the verified minima into branches (§5): the side of the separating mode's score.

Minima closer than ``tol`` (M-norm RMS distance over the bounding-box diagonal, :func:`defop.training.minima.rms`)
at one Q_k are one. Where a Q_k holds two distinct minima, their difference is the mode that separates the
branches: u is the leading M-weighted principal direction of these differences (for the bar: the buckling mode),
and every minimum gets the score s(X) = ⟨X − x, u⟩_M. The threshold t(Q) = t_0 + t_1 · (Q − P) is the least-squares
plane through the midpoints of the coexisting pairs' scores; branch = side of t(Q).

Justification: two minima at one Q are on different sides (checked: ``conflicts`` counts Q_k where two distinct
minima fell on one side; the lower is kept), and along a branch score − t is continuous, so it changes side only
where the two sheets meet without a fold (one minimum), never across a fold. A constant t does not do: on the bar
the minimum the drag continues from the bottom of a compressed column (the mid-bar point up) has a score that grows
as the handle moves down, past the other sheet's scores higher up the column (measured: +0.021 at
q − p = (−0.15, −0.3), where the wedge's midpoints are about +0.05). With no Q_k holding two minima there is one
branch. Label 0 is the branch holding the rest pose (the side of s(x) = 0), so labels are stable. Each kept minimum
gets its **stability margin** (:func:`defop.training.branches.stability_margin`): the reduced Hessian's eigenvalue of
the eigenvector most parallel to u, which vanishes at the branch's fold.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ... import options as opt
from ...variational.solver import Solver
from ..minima import distinct_minima
from .eigen import stability_margin

__all__ = [
    "SampledBranch",
    "SampledBranches",
    "check_mesh",
    "distinct_at",
    "group",
    "plane",
    "score",
    "separating_mode",
    "threshold_plane",
]


@dataclasses.dataclass
class SampledBranch:
    """The minima of one branch at the samples where it exists.

    Attributes
    ----------
    label : int
    samples : (k,) numpy int array
        Indices of the samples Q_k where the branch has a minimum (its domain on the samples).
    X : (k, n_vertices, d) numpy array
    energy, margin : (k,) numpy arrays
        E and the stability margin (:func:`stability_margin` along u) of each minimum (NaN where not computed).
    side : int
        +1 when the branch's scores are above the threshold t, −1 below.
    folds : (f, n_moving, d) numpy array or None
        After :func:`certify_branches`: the fold points (bisected edge of the domain); None before.
    segments : (s, 2, n_moving, d) numpy array or None
        The edge of the domain between the fold points (marching squares, refined across each cell).
    absent, uncertified : (·,) numpy int arrays
        After :func:`certify_branches`: grid samples certified absent, and bordering samples left uncertified.
    """

    label: int
    samples: np.ndarray
    X: np.ndarray
    energy: np.ndarray
    margin: np.ndarray
    side: int
    folds: np.ndarray = None
    segments: np.ndarray = None
    absent: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    uncertified: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))

    def report(self, Q):
        """count, domain extent (min and max of each coordinate of Q over the branch's samples), energy range."""
        q = np.asarray(Q)[self.samples].reshape(len(self.samples), -1)
        return {
            "label": self.label,
            "count": int(len(self.samples)),
            "q_min": q.min(axis=0),
            "q_max": q.max(axis=0),
            "energy": (float(self.energy.min()), float(self.energy.max())),
        }


@dataclasses.dataclass
class SampledBranches:
    """The branches of D^E at the samples (:func:`group`).

    Attributes
    ----------
    samples : (m, n_moving, d) numpy array
    branches : list of SampledBranch
        Label 0 holds the rest pose.
    mode : (n_vertices, d) numpy array
        u (M-unit), zeros with one branch.
    threshold : (1 + d n_moving,) numpy array
        t(Q) = t[0] + t[1:] · (Q − P).
    distinct : (m,) numpy int array
        Distinct verified minima found at each sample.
    conflicts : int
        Samples where two distinct minima fell on one side of t (the lower was kept).
    lowest : (m,) numpy int array
        The label of the lowest minimum at each sample (the single-valued training's choice).
    margin_seconds : float
        CPU seconds of the stability margins (``time.process_time``).
    certify_seconds : float
        CPU seconds of :func:`certify_branches` (certification and bisection solves).
    grid : int or None
        The number of grid samples (the first ``grid`` of ``samples``; edge minima follow); None: all.
    third : (·,) numpy int array
        Samples where more than two distinct minima were seen (discovery or certification): reported, not
        resolved (two branches, the lower minimum kept on each side).
    found : int
        Samples certification found on a branch that discovery had missed.
    """

    samples: np.ndarray
    branches: list
    mode: np.ndarray
    threshold: np.ndarray
    distinct: np.ndarray
    conflicts: int
    lowest: np.ndarray
    margin_seconds: float = 0.0
    certify_seconds: float = 0.0
    grid: int = None
    third: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    found: int = 0

    def reports(self):
        """Per branch: :meth:`SampledBranch.report`."""
        return [b.report(self.samples) for b in self.branches]


def check_mesh(shape, branches):
    """Raise ValueError unless ``branches`` were grouped on ``shape``: its mesh (vertices, dimension) and its moving
    handles."""
    n, d = shape.mesh.V.shape
    P = np.shape(shape.P_moving)
    Q = np.shape(branches.samples)
    if len(Q) != 3 or Q[1:] != P:
        raise ValueError(
            f"branches.samples have shape {Q}, and shape {shape.name!r} has {P[0]} moving handles in {P[1]}D: "
            "the branches were grouped for another shape (pass the shape they were grouped on)"
        )
    meshes = {np.shape(branches.mode)} | {np.shape(b.X)[1:] for b in branches.branches}
    if meshes != {(n, d)}:
        got = sorted(meshes)
        raise ValueError(
            f"the branches were grouped on a mesh of {got[0][0]} vertices in {got[0][-1]}D, and shape "
            f"{shape.name!r} has a mesh of {n} vertices in {d}D: certify and fit them with the shape (and mesh) "
            "they were grouped on"
        )


def separating_mode(mesh, minima, pairs):
    """u (n_vertices, d), M-unit: the leading M-weighted principal direction of the differences of coexisting minima."""
    w = np.sqrt(mesh.mass_matrix.diagonal())[:, None]
    D = np.stack([((minima.X[k, a] - minima.X[k, b]) * w).ravel() for k, a, b in pairs])
    u = np.linalg.svd(D, full_matrices=False)[2][0].reshape(-1, mesh.V.shape[1]) / w
    return u / np.sqrt(np.einsum("v,vc->", mesh.mass_matrix.diagonal(), u**2))


def score(mesh, u, X):
    """s(X) = ⟨X − x, u⟩_M: the score of a configuration X along the separating mode u."""
    return float(np.einsum("v,vc,vc->", mesh.mass_matrix.diagonal(), X - mesh.V, u))


def distinct_at(mesh, minima, k, tol):
    """Sources (list of int) of the distinct verified minima at sample k, lowest energy first (M-weighted RMS)."""
    X, E, ok = minima.X[k], minima.energy[k], minima.converged[k]
    return distinct_minima(X, E, ok, tol, mesh.bbox_diagonal, metric="rms", mesh=mesh)


def group(shape, minima, tol=1e-3, energy="sarap", margins=True):
    """Group the verified minima into branches by the side of the separating mode's score (module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    minima : defop.training.branches.Minima
    tol : float
        Minima at one sample closer than ``tol`` × bbox diagonal (M-weighted RMS) are one.
    energy : str
        The energy of the minima (for their stability margins, :func:`stability_margin` along u).
    margins : bool
        Compute the stability margins; False leaves them NaN (the domain is fitted from
        :func:`defop.training.branches.certify_branches`' labels).

    Returns
    -------
    SampledBranches
    """
    tol = opt.positive("tol", tol)
    mesh, m = shape.mesh, len(minima.samples)
    if np.shape(minima.X)[2:] != mesh.V.shape or np.shape(minima.samples)[1:] != np.shape(shape.P_moving):
        raise ValueError(
            f"minima hold configurations of shape {np.shape(minima.X)[2:]} at samples of shape "
            f"{np.shape(minima.samples)[1:]}, and shape {shape.name!r} has a mesh of {mesh.V.shape} and moving "
            f"handles of {np.shape(shape.P_moving)}: the minima were discovered on another mesh or shape"
        )
    kept = [distinct_at(mesh, minima, k, tol) for k in range(m)]
    if not any(kept):
        raise ValueError("no sample holds a verified minimum: nothing to group")
    pairs = [(k, c[0], c[1]) for k, c in enumerate(kept) if len(c) >= 2]
    if not pairs:  # one branch: the lowest minimum at each sample
        u, t, side_of = np.zeros_like(mesh.V), np.zeros(1 + mesh.V.shape[1] * len(shape.P_moving)), {}
    else:
        u = separating_mode(mesh, minima, pairs)
        mid = [(k, score(mesh, u, minima.X[k, a]), score(mesh, u, minima.X[k, b])) for k, a, b in pairs]
        t = threshold_plane(shape, minima.samples, mid)
        rest_side = 1 if -t[0] >= 0 else -1  # s(x) = 0 at the rest pose, t(P) = t[0]
        side_of = {rest_side: 0, -rest_side: 1}
    members, conflicts, lowest = _label(shape, minima, kept, u, t, side_of)
    sides = {v: s for s, v in side_of.items()} if pairs else {0: 1}
    branches, solver, t0 = [], Solver(mesh, shape.handles, energy=energy), time.process_time()
    for label, pts in members.items():
        ks = np.array([k for k, _ in pts], dtype=np.int64)
        cs = np.array([c for _, c in pts], dtype=np.int64)
        margin = np.array(
            [stability_margin(solver, minima.X[k, c], u if pairs else None) if margins else np.nan for k, c in pts]
        )
        branches.append(SampledBranch(label, ks, minima.X[ks, cs], minima.energy[ks, cs], margin, sides[label]))
    distinct = np.array([len(c) for c in kept])
    third = np.flatnonzero(distinct > 2)
    seconds = time.process_time() - t0
    return SampledBranches(minima.samples, branches, u, t, distinct, conflicts, lowest, seconds, third=third)


def _label(shape, minima, kept, u, t, side_of):
    """Each kept minimum's branch: members {label: [(k, source)]}, conflicts, the lowest minimum's label per sample."""
    members = {0: [], 1: []} if side_of else {0: []}
    conflicts, lowest = 0, np.full(len(kept), -1)
    for k, cs in enumerate(kept):
        seen = set()
        for c in cs:  # lowest first: on a conflict the lower minimum stays
            label = 0
            if side_of:
                above = score(shape.mesh, u, minima.X[k, c]) - plane(t, minima.samples[k], shape.P_moving) >= 0
                label = side_of[1 if above else -1]
            if label in seen:
                conflicts += 1
                continue
            seen.add(label)
            members[label].append((k, c))
            if lowest[k] < 0:
                lowest[k] = label
    return members, conflicts, lowest


def plane(t, Q, P):
    """t(Q) = t[0] + t[1:] · (Q − P): the threshold at Q (n_moving, d)."""
    return float(t[0] + t[1:] @ (np.asarray(Q) - P).ravel())


def threshold_plane(shape, samples, pairs):
    """t (1 + d n_moving,): the least-squares plane t(Q) through the midpoints of the coexisting minima's scores.

    Parameters
    ----------
    pairs : list of (k, s_a, s_b)
        Sample index and the two minima's scores.
    """
    A = np.array([np.concatenate([[1.0], (samples[k] - shape.P_moving).ravel()]) for k, _, _ in pairs])
    y = np.array([(a + b) / 2 for _, a, b in pairs])
    return np.linalg.lstsq(A, y, rcond=None)[0]


# --------------------------------------------------------------------------- fitting

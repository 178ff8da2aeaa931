"""A multi-valued deformation operator: one closed-form DefOp per branch of D^E and the choice between them (§5).

Problem (6) is non-convex, so D^E is multi-valued: the bar of Fig. 10, pushed in, buckles up or down. A
single-valued D_{Φ,Ψ} fitted to the lowest minimum at each Q_k averages across the jump. Here every branch b
(a sheet of local minima, found by :mod:`defop.training.branches`) gets its own operator and three scalar closed
forms with the same Ψ (:func:`defop.operator.fit.fit_values`):

    D_b(·, Q) = Ψ_b(Q) W_b                   (Eq. 3 on the branch's samples; Prop. 2 and (8b) as for DefOp)
    E_b(Q)    = Ψ_b(Q) · e_b                 (the energy of the branch's minimum)
    λ²_b(Q)   = Ψ_b(Q) · l_b                 (the square of the smallest eigenvalue of the reduced Hessian)
    s_b(Q)    = σ_b (⟨D_b(·, Q) − x, u⟩_M − t(Q))   (the side of the branch's mode score; exact, linear in D_b)

At a fold (saddle-node) a branch's smallest Hessian eigenvalue vanishes like the square root of the distance to
it, so λ² is smooth and crosses zero there: λ²_b(Q) > 0 estimates where b exists as a local minimum. Where two
branches meet without a fold (one minimum), the score on the mode u of the branches' difference crosses its
threshold t(Q) (a plane in Q) continuously: b is on its side there when s_b(Q) ≥ 0 or s_b is the largest of the
branches' sides (the nearest sheet). So

    exists_b(Q)  ⇔  λ²_b(Q) > 0  and  (s_b(Q) ≥ 0 or b = argmax_c s_c(Q)).

Modes: ``global`` takes the existing branch of lowest E_b(Q) (no history); :class:`FollowSession` stays on its
branch while it exists and jumps to the existing branch of lowest E_b when it leaves (the solver's warm-started
drag, hysteresis included). A Q where no branch exists (beyond every fold, or far outside the samples) takes the
branch with the largest λ²_b (the nearest) and an :class:`ExtrapolationWarning`. Every path is a DefOp
evaluation plus three dot products: closed-form speed.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from . import compress as compress_policy
from . import io as io_mod
from .defop import DefOp, ExtrapolationWarning, not_finite_error

__all__ = ["Branch", "BranchedOperator", "FollowSession", "MODES"]

MODES = ("global", "follow")


class Branch:
    """One branch b: its DefOp D_b and the coefficients of E_b, λ²_b and the side score s_b (module docstring).

    Parameters
    ----------
    label : int
        Stable label (0 holds the rest pose).
    op : DefOp
    energy, margin : (|Ψ_b|,) numpy arrays
        e_b and l_b.
    side : int
        σ_b, +1 or −1.
    """

    def __init__(self, label, op, energy, margin, side):
        self.label = int(label)
        self.op = op
        self.energy_w = np.asarray(energy, dtype=float)
        self.margin_w = np.asarray(margin, dtype=float)
        self.side = int(side)
        for name, w in (("energy", self.energy_w), ("margin", self.margin_w)):
            if w.shape != (op.handle_basis.size,) or not np.isfinite(w).all():
                raise ValueError(f"{name} must be {op.handle_basis.size} finite coefficients, got {w.shape}")
        if self.side not in (1, -1):
            raise ValueError(f"side must be +1 or -1, got {side!r}")
        self.score_w = None  # set by BranchedOperator (needs u, t)

    def __repr__(self):
        return f"Branch({self.label}, {self.op.n_samples} samples, side {self.side:+d})"


class BranchedOperator:
    """A multi-valued closed-form operator: the branches of D^E, ``global`` and ``follow`` evaluation.

    Parameters
    ----------
    branches : list of Branch
        Same mesh, handles and moving flags; labels 0..B−1 in order; branch 0 holds the rest pose.
    mode : (n_vertices, d) numpy array
        u, the M-unit mode whose score separates the branches (zeros with one branch).
    threshold : (1 + d n_moving,) numpy array
        t(Q) = t[0] + t[1:] · (Q − P), the plane separating the branches' scores.
    meta : dict, optional

    Attributes
    ----------
    labels : tuple of int
    """

    def __init__(self, branches, mode, threshold, meta=None):
        if not branches:
            raise ValueError("branches must hold at least one Branch")
        got = [b.label for b in branches]
        if got != list(range(len(branches))):
            raise ValueError(f"branch labels must be 0..{len(branches) - 1} in order, got {got}")
        ref = branches[0].op
        for b in branches[1:]:
            ref.check_mesh(b.op.mesh)
            if not (np.array_equal(b.op.handles, ref.handles) and np.array_equal(b.op.moving, ref.moving)):
                raise ValueError(f"branch {b.label} has other handles than branch 0")
        self.branches = list(branches)
        mode = np.asarray(mode, dtype=float)
        if mode.size != ref.n_vertices * ref.d or not np.isfinite(mode).all():
            raise ValueError(
                f"mode must be {ref.n_vertices} x {ref.d} finite numbers (one row per vertex), got shape {mode.shape}"
                + ("" if mode.size != ref.n_vertices * ref.d else " with non-finite entries")
            )
        self.mode = mode.reshape(ref.n_vertices, ref.d)
        self.threshold = np.asarray(threshold, dtype=float).ravel()
        if self.threshold.shape != (1 + ref.P.size,) or not np.isfinite(self.threshold).all():
            raise ValueError(f"threshold must be {1 + ref.P.size} finite numbers, got {self.threshold.shape}")
        self.meta = dict(meta or {})
        mass = np.repeat(ref.mesh.mass_matrix.diagonal(), ref.d)
        mu = (mass * self.mode.ravel()).ravel()
        x_u = float(ref.mesh.V.ravel() @ mu)
        for b in self.branches:  # s_b(Q) = σ_b (Ψ(Q) W_b M u − ⟨x, u⟩_M − t(Q)): exact, Ψ's 1 and z = (Q − P)/scale
            w = b.op.W @ mu
            w[0] -= x_u + self.threshold[0]
            w[1 : 1 + ref.P.size] -= self.threshold[1:] * b.op.handle_basis.scale
            b.score_w = b.side * w

    # ------------------------------------------------------------------ properties
    @property
    def labels(self):
        return tuple(b.label for b in self.branches)

    @property
    def mesh(self):
        return self.branches[0].op.mesh

    @property
    def P(self):
        return self.branches[0].op.P

    @property
    def n_moving(self):
        return self.branches[0].op.n_moving

    def __len__(self):
        return len(self.branches)

    def __repr__(self):
        return f"BranchedOperator({self.meta.get('shape', '?')}, {len(self)} branches: {self.branches})"

    def check_label(self, label, name="label"):
        """The branch of a label; ValueError naming ``name`` for anything else."""
        if (
            isinstance(label, (bool, np.bool_))
            or not isinstance(label, (int, np.integer))
            or not (0 <= label < len(self))
        ):
            raise ValueError(f"{name} must be one of the branch labels {self.labels}, got {label!r}")
        return self.branches[int(label)]

    # ------------------------------------------------------------------ scalar closed forms
    def estimates(self, Q):
        """E_b(Q), λ²_b(Q), s_b(Q) for every branch: three (B,) arrays (one Q) or (k, B) arrays (a batch)."""
        psis = [b.op.psi(Q) for b in self.branches]  # validates Q (shape, NaN) like DefOp
        with np.errstate(over="ignore", invalid="ignore"):  # a far Q: the clear error below, not numpy's warning
            out = [
                np.stack([p @ getattr(b, w) for p, b in zip(psis, self.branches)], axis=-1)
                for w in ("energy_w", "margin_w", "score_w")
            ]
        bad = ~np.all([np.isfinite(o).reshape(-1, len(self)).all(axis=1) for o in out], axis=0)
        if bad.any():  # Ψ(Q) overflowed (inf, NaN): no estimate to choose from, no argmax over NaN
            raise not_finite_error(self.branches[0].op, np.reshape(Q, (-1, *self.P.shape))[bad], "Ψ(Q) · (e, l, s)")
        return tuple(out)

    def exists(self, Q):
        """(B,) or (k, B) bool: where each branch exists (module docstring)."""
        _, lam2, side = self.estimates(Q)
        return existing(lam2, side)

    def choose(self, Q):
        """The ``global`` branch label at each Q: the existing branch of lowest E_b. (k,) int or int."""
        E, lam2, side = self.estimates(Q)
        labels, far = lowest_existing(E, lam2, side)
        warn_far(far)
        return labels if np.ndim(labels) else int(labels)

    # ------------------------------------------------------------------ evaluation
    def __call__(self, Q, mode="global", branch=None):
        """D(·, Q) on the ``global`` branch at each Q, or on a given ``branch`` (a label).

        Parameters
        ----------
        Q : (n_moving, d) or (k, n_moving, d) numpy array
        mode : {"global"}
            ``follow`` needs a history: use :meth:`session`.
        branch : int, optional
            Evaluate this branch's D_b everywhere (no choice).

        Returns
        -------
        X : (n_vertices, d) or (k, n_vertices, d) numpy array
        """
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if mode == "follow":
            raise ValueError("mode 'follow' depends on the drag's history: use op.session() and session(Q)")
        if branch is not None:
            return self.check_label(branch, "branch").op(Q)
        labels = self.choose(Q)
        if np.ndim(labels) == 0:
            return self.branches[labels].op(Q)
        return self.on_branches(labels, Q)

    def on_branches(self, labels, Qs):
        """D_{labels[i]}(·, Qs[i]) for a batch: (k, n_vertices, d), one batch evaluation per branch."""
        Qs = np.asarray(Qs, dtype=float)
        labels = np.asarray(labels)
        if Qs.ndim != 3 or labels.shape != (len(Qs),):
            raise ValueError(f"labels must be one branch label per Q of Qs, got {labels.shape} for Qs {Qs.shape}")
        unknown = sorted(set(labels.tolist()) - set(self.labels))
        if unknown:
            raise ValueError(f"labels must be branch labels {self.labels}, got {unknown}")
        out = np.empty((len(Qs), self.mesh.n_vertices, self.branches[0].op.d))
        for b in self.branches:
            rows = labels == b.label
            if rows.any():
                out[rows] = b.op(Qs[rows])
        return out

    def session(self, branch=None):
        """A :class:`FollowSession` (a drag), on ``branch`` or (default) on the global branch at its first Q."""
        return FollowSession(self, branch)

    # ------------------------------------------------------------------ compression and files
    def compress(self, rank=None, tol=compress_policy.TOL, dtype=np.float32):
        """:meth:`DefOp.compress` on every branch (the guarantees stay exact on each). Returns ``self``."""
        for b in self.branches:
            b.op.compress(rank, tol, dtype)
        return self

    def save(self, path):
        """Save as one .npz of kind ``branched`` (:func:`defop.operator.io.save_branched`)."""
        io_mod.save_branched(self, path)

    @classmethod
    def load(cls, path):
        """Load a file written by :meth:`save` (checked as :meth:`DefOp.load` checks its files)."""
        return io_mod.load_branched(path, cls, Branch, DefOp)


def existing(lam2, side):
    """exists_b from λ²_b and s_b (B,) or (k, B): λ² > 0 and (s ≥ 0 or s is the largest side)."""
    lam2, side = np.asarray(lam2), np.asarray(side)
    nearest = side >= side.max(axis=-1, keepdims=True)
    return (lam2 > 0) & ((side >= 0) | nearest)


def lowest_existing(E, lam2, side):
    """(labels, far): the existing branch of lowest E at each row; where none exists, the largest λ² (far = True)."""
    ok = existing(lam2, side)
    far = ~ok.any(axis=-1)
    labels = np.where(far, np.argmax(lam2, axis=-1), np.argmin(np.where(ok, E, np.inf), axis=-1))
    return labels, far


def warn_far(far):
    """The ExtrapolationWarning of a Q where no branch exists."""
    if np.any(far):
        warnings.warn(
            f"{int(np.sum(far))} handle configuration(s) lie outside every branch's domain (beyond every fold or "
            "far from the samples): the nearest branch (largest estimated stability margin) extrapolates",
            ExtrapolationWarning,
            stacklevel=3,
        )


class FollowSession:
    """A ``follow`` drag: stays on its branch while Q is in the branch's domain, else jumps (module docstring).

    Parameters
    ----------
    op : BranchedOperator
    branch : int, optional
        The starting branch; default: the global branch at the first Q.

    Attributes
    ----------
    branch : int or None
        The current label (None before the first frame after :meth:`reset` without a branch).
    jumps : list of (int, int, int)
        (frame, from, to) of every jump.
    """

    def __init__(self, op, branch=None):
        self.op = op
        self.frame = 0
        self.jumps = []
        self.branch = None if branch is None else op.check_label(branch, "branch").label

    def reset(self, branch=None):
        """Start again (frame 0, no jumps), on ``branch`` or on the global branch at the next Q."""
        new = None if branch is None else self.op.check_label(branch, "branch").label
        self.branch, self.frame, self.jumps = new, 0, []

    def set(self, branch):
        """Move the drag to ``branch`` (a label) from the next frame on."""
        self.branch = self.op.check_label(branch, "branch").label

    def _next(self, Q):
        """(label, jump or None, far) at Q without changing the state: every check runs here (a rejected Q changes
        nothing)."""
        Q = opt.real_array("Q", Q)
        if Q.shape != self.op.P.shape:
            raise ValueError(
                f"Q must have shape {self.op.P.shape} (one configuration of the moving handles), got {Q.shape}"
            )
        E, lam2, side = self.op.estimates(Q)  # raises on NaN/inf Q or a non-finite Ψ(Q), before any state changes
        ok = existing(lam2, side)
        if self.branch is not None and ok[self.branch]:
            return self.branch, None, False
        label, far = lowest_existing(E, lam2, side)
        label = int(label)
        jump = (self.frame, self.branch, label) if self.branch is not None and label != self.branch else None
        return label, jump, bool(far)

    def _commit(self, label, jump):
        if jump is not None:
            self.jumps.append(jump)
        self.branch = label
        self.frame += 1
        return label

    def step(self, Q):
        """The label of the branch D is evaluated on at Q (one configuration (n_moving, d)), updating the state.

        A Q that is rejected (wrong shape, NaN, inf, or so far that Ψ(Q) is not finite) raises ValueError and
        changes nothing: branch, frame and jumps stay as they were.
        """
        label, jump, far = self._next(Q)
        warn_far(far)
        return self._commit(label, jump)

    def __call__(self, Q):
        """D(·, Q) on the followed branch: (n_vertices, d). A rejected Q changes nothing (:meth:`step`)."""
        label, jump, far = self._next(Q)
        X = self.op.branches[label].op(Q)  # may still raise (D(·, Q) not finite): the state is not yet changed
        warn_far(far)
        self._commit(label, jump)
        return X

    def run(self, Qs):
        """Follow a path Qs (k, n_moving, d): (labels (k,), X (k, n_vertices, d))."""
        Qs = opt.real_array("Qs", Qs)
        if Qs.ndim != 3:
            raise ValueError(f"Qs must have shape (k, {self.op.n_moving}, d), got {Qs.shape}")
        state = (self.branch, self.frame, list(self.jumps))
        try:  # one call: a rejected frame anywhere on the path changes nothing
            labels = np.array([self.step(q) for q in Qs], dtype=np.int64)
            return labels, self.op.on_branches(labels, Qs)
        except ValueError:
            self.branch, self.frame, self.jumps = state
            raise

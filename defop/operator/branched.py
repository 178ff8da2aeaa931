"""A multi-valued deformation operator: one closed-form DefOp per branch of D^E and the choice between them (§5).

Problem (6) is non-convex, so D^E is multi-valued: the bar of Fig. 10, pushed in, buckles up or down. A
single-valued D_{Φ,Ψ} fitted to the lowest minimum at each Q_k averages across the jump. Here every branch b
(a sheet of local minima, found by :mod:`defop.training.branches`) gets its own operator, two scalar closed forms
with the same Ψ (:func:`defop.operator.fit.fit_values`) and its domain:

    D_b(·, Q) = Ψ_b(Q) W_b                   (Eq. 3 on the branch's samples; Prop. 2 and (8b) as for DefOp)
    E_b(Q)    = Ψ_b(Q) · e_b                 (the energy of the branch's minimum)
    s_b(Q)    = σ_b (⟨D_b(·, Q) − x, u⟩_M − t(Q))   (the side of the branch's mode score; exact, linear in D_b)
    g_b(Q)    = Ψ_D(Q) · w_D                 (b's domain: > 0 where b exists, :mod:`defop.operator.domains`)

g_b interpolates the signed distance to b's fold points, fitted from both sides: + where b was found or certified
present, − where a solve warm-started from b left it (certified absent, :mod:`defop.training.branch_domains`), 0 at
the bisected edge between them. (Files of format 1 carry λ²_b(Q) = Ψ_b(Q) · l_b, the square of b's smallest
Hessian eigenvalue along the mode, fitted on b's own samples only, as g_b.) Where two branches meet without a fold
(one minimum), the score on the mode u of the branches' difference crosses its threshold t(Q) (a plane in Q)
continuously: b is on its side there when s_b(Q) ≥ 0 or s_b is the largest of the branches' sides (the nearest
sheet). So

    exists_b(Q)  ⇔  g_b(Q) > 0  and  (s_b(Q) ≥ 0 or b = argmax_c s_c(Q)).

Modes: ``global`` takes the existing branch of lowest E_b(Q) (no history); :class:`FollowSession` stays on its
branch while it exists and jumps to the existing branch of lowest E_b when it leaves (the solver's warm-started
drag, hysteresis included). A Q where no branch exists takes the branch with the largest g_b (the nearest) and an
:class:`ExtrapolationWarning`; so does every path at a Q outside the samples' box enlarged by one grid spacing,
whatever g_b says there. Every path is a DefOp evaluation plus a few dot products: closed-form speed. A rejected
Q (NaN, inf, a wrong shape, Ψ(Q) not finite) raises ValueError and changes no session's state.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from . import compress as compress_policy
from . import io as io_mod
from .defop import DefOp, ExtrapolationWarning, not_finite_error
from .domains import Domain, box_of, outside_box

__all__ = ["Branch", "BranchedOperator", "FollowSession", "MODES"]

MODES = ("global", "follow")


class Branch:
    """One branch b: its DefOp D_b, the coefficients of E_b and s_b, and its domain g_b (module docstring).

    Parameters
    ----------
    label : int
        Stable label (0 holds the rest pose).
    op : DefOp
    energy : (|Ψ_b|,) numpy array
        e_b.
    margin : (|Ψ_b|,) numpy array or None
        l_b, the coefficients of λ²_b (format 1's domain function); None with ``domain``.
    side : int
        σ_b, +1 or −1.
    domain : defop.operator.domains.Domain, optional
        g_b fitted from both sides (:func:`defop.operator.domains.fit_domain`); default (a version-1 file)
        λ²_b = Ψ_b(Q) · l_b, read as a domain on Ψ_b.
    """

    def __init__(self, label, op, energy, margin, side, domain=None):
        self.label = int(label)
        self.op = op
        self.energy_w = np.asarray(energy, dtype=float)
        self.margin_w = None if margin is None else np.asarray(margin, dtype=float)
        self.side = int(side)
        for name, w in (("energy", self.energy_w), ("margin", self.margin_w)):
            if w is None and domain is not None:
                continue
            if w is None or w.shape != (op.handle_basis.size,) or not np.isfinite(w).all():
                got = None if w is None else w.shape
                raise ValueError(f"{name} must be {op.handle_basis.size} finite coefficients, got {got}")
        if self.side not in (1, -1):
            raise ValueError(f"side must be +1 or -1, got {side!r}")
        if domain is not None and not np.array_equal(domain.basis.P, op.P):
            raise ValueError(f"branch {label}'s domain is a function of other handles than its operator")
        self.domain = domain if domain is not None else Domain(op.handle_basis, self.margin_w, own=False)
        self.score_w = None  # set by BranchedOperator (needs u, t)

    def __repr__(self):
        return f"Branch({self.label}, {self.op.n_samples} samples, side {self.side:+d}, {self.domain})"


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
    box : (2, d n_moving) numpy array, optional
        The lowest and highest Q − P of the samples' grid, enlarged by one spacing
        (:func:`defop.operator.domains.box_of`); beyond it every path warns. Default: the box of every branch's
        training samples, enlarged by their smallest distance.

    Attributes
    ----------
    labels : tuple of int
    """

    def __init__(self, branches, mode, threshold, meta=None, box=None):
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
        self.box = default_box(self.branches) if box is None else np.asarray(box, dtype=float)
        if self.box.shape != (2, ref.P.size) or not np.isfinite(self.box).all() or (self.box[0] > self.box[1]).any():
            raise ValueError(f"box must be (2, {ref.P.size}) finite lower and upper bounds, got {self.box.shape}")
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
    def estimates(self, Q, _warn=2):
        """E_b(Q), g_b(Q), s_b(Q) for every branch: three (B,) arrays (one Q) or (k, B) arrays (a batch).

        g_b is the domain function (:mod:`defop.operator.domains`; λ²_b in format-1 files). A Q outside the box
        warns (:class:`ExtrapolationWarning`); a Q whose estimates are not finite raises ValueError naming Q.
        """
        psis = [b.op.psi(Q) for b in self.branches]  # validates Q (shape, NaN) like DefOp
        with np.errstate(over="ignore", invalid="ignore"):  # a far Q: the clear error below, not numpy's warning
            out = [np.stack([p @ b.energy_w for p, b in zip(psis, self.branches)], axis=-1)]
            out.append(
                np.stack(
                    [
                        b.domain(Q, p if b.domain.basis is b.op.handle_basis else None)
                        for p, b in zip(psis, self.branches)
                    ],
                    -1,
                )
            )
            out.append(np.stack([p @ b.score_w for p, b in zip(psis, self.branches)], axis=-1))
        bad = ~np.all([np.isfinite(o).reshape(-1, len(self)).all(axis=1) for o in out], axis=0)
        if bad.any():  # Ψ(Q) overflowed (inf, NaN): no estimate to choose from, no argmax over NaN
            raise not_finite_error(self.branches[0].op, np.reshape(Q, (-1, *self.P.shape))[bad], "Ψ(Q) · (e, g, s)")
        if _warn:
            self.warn_box(Q, _warn + 1)
        return tuple(out)

    def warn_box(self, Q, stacklevel=2):
        """The ExtrapolationWarning of a Q (or batch) outside the samples' box enlarged by one spacing."""
        far = np.atleast_1d(outside_box(self.box, self.P, Q))
        if far.any():
            warnings.warn(
                f"{int(far.sum())} handle configuration(s) lie outside the box of the branches' samples enlarged by "
                "one grid spacing: every branch's operator and domain extrapolate there",
                ExtrapolationWarning,
                stacklevel=stacklevel,
            )

    def exists(self, Q):
        """(B,) or (k, B) bool: where each branch exists (module docstring)."""
        _, g, side = self.estimates(Q, _warn=3)
        return existing(g, side)

    def choose(self, Q, _warn=2):
        """The ``global`` branch label at each Q: the existing branch of lowest E_b. (k,) int or int."""
        E, g, side = self.estimates(Q, _warn=_warn + 1)
        labels, far = lowest_existing(E, g, side)
        warn_far(far, _warn + 1)
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
            X = self.check_label(branch, "branch").op(Q)  # validates Q
            self.warn_box(Q, 3)
            return X
        labels = self.choose(Q, _warn=3)
        if np.ndim(labels) == 0:
            return self.branches[labels].op(Q)
        return self._on_branches(labels, Q)

    def on_branches(self, labels, Qs):
        """D_{labels[i]}(·, Qs[i]) for a batch: (k, n_vertices, d), one batch evaluation per branch."""
        Qs = np.asarray(Qs, dtype=float)
        labels = np.asarray(labels)
        if Qs.ndim != 3 or labels.shape != (len(Qs),):
            raise ValueError(f"labels must be one branch label per Q of Qs, got {labels.shape} for Qs {Qs.shape}")
        unknown = sorted(set(labels.tolist()) - set(self.labels))
        if unknown:
            raise ValueError(f"labels must be branch labels {self.labels}, got {unknown}")
        X = self._on_branches(labels, Qs)
        self.warn_box(Qs, 3)
        return X

    def _on_branches(self, labels, Qs):
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
        return io_mod.load_branched(path, cls, Branch, DefOp, Domain)


def existing(g, side):
    """exists_b from g_b and s_b (B,) or (k, B): g > 0 and (s ≥ 0 or s is the largest side)."""
    g, side = np.asarray(g), np.asarray(side)
    nearest = side >= side.max(axis=-1, keepdims=True)
    return (g > 0) & ((side >= 0) | nearest)


def lowest_existing(E, g, side):
    """(labels, far): the existing branch of lowest E at each row; where none exists, the largest g (far = True)."""
    ok = existing(g, side)
    far = ~ok.any(axis=-1)
    labels = np.where(far, np.argmax(g, axis=-1), np.argmin(np.where(ok, E, np.inf), axis=-1))
    return labels, far


def default_box(branches):
    """The box of every branch's training samples, enlarged by their smallest distance (format-1 files)."""
    op = branches[0].op
    Qs = np.concatenate([b.op.train_samples for b in branches if b.op.train_samples is not None] or [op.P[None]])
    flat = (Qs - op.P).reshape(len(Qs), -1)
    D = np.abs(flat[:, None] - flat[None]).max(axis=-1)
    spacing = float(D[D > 0].min()) if (D > 0).any() else op.mesh.bbox_diagonal
    return box_of(op.P, Qs, spacing)


def warn_far(far, stacklevel=3):
    """The ExtrapolationWarning of a Q where no branch exists."""
    if np.any(far):
        warnings.warn(
            f"{int(np.sum(far))} handle configuration(s) lie outside every branch's domain (beyond every fold or "
            "far from the samples): the nearest branch (largest domain function g_b) extrapolates",
            ExtrapolationWarning,
            stacklevel=opt.user_stacklevel(),
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

    def _next(self, Q, depth):
        """(label, jump or None, far) at Q without changing the state: every check runs here (a rejected Q changes
        nothing). ``depth``: frames between the user's call and this one (for the warnings' stacklevel)."""
        Q = opt.real_array("Q", Q)
        if Q.shape != self.op.P.shape:
            raise ValueError(
                f"Q must have shape {self.op.P.shape} (one configuration of the moving handles), got {Q.shape}"
            )
        if self.branch is not None and self._stays(Q):
            return self.branch, None, False
        E, g, side = self.op.estimates(Q, _warn=depth + 2)  # raises on NaN/inf Q or a non-finite Ψ(Q)
        ok = existing(g, side)
        if self.branch is not None and ok[self.branch]:
            return self.branch, None, False
        label, far = lowest_existing(E, g, side)
        label = int(label)
        jump = (self.frame, self.branch, label) if self.branch is not None and label != self.branch else None
        return label, jump, bool(far)

    def _stays(self, Q):
        """The fast test of a frame inside the box: the current branch exists with s_b ≥ 0 (finite and positive
        g_b; the other branches are not needed). False sends the frame to the full test."""
        b, box = self.op.branches[self.branch], self.op.box
        dz = (Q - b.op.handle_basis.P).ravel()
        if not ((dz >= box[0]).all() and (dz <= box[1]).all()):  # NaN compares False: the full test raises
            return False
        psi = b.op.handle_basis.evaluate_one(dz / b.op.handle_basis.scale)  # inside the box: Ψ is finite
        g = b.domain.basis.evaluate_one(dz / b.domain.basis.scale) @ b.domain.w
        return bool(g > 0 and psi @ b.score_w >= 0)

    def _commit(self, label, jump):
        if jump is not None:
            self.jumps.append(jump)
        self.branch = label
        self.frame += 1
        return label

    def step(self, Q, _depth=1):
        """The label of the branch D is evaluated on at Q (one configuration (n_moving, d)), updating the state.

        A Q that is rejected (wrong shape, NaN, inf, or so far that Ψ(Q) is not finite) raises ValueError and
        changes nothing: branch, frame and jumps stay as they were.
        """
        label, jump, far = self._next(Q, _depth + 1)
        if far:
            warn_far(far, _depth + 2)
        return self._commit(label, jump)

    def __call__(self, Q):
        """D(·, Q) on the followed branch: (n_vertices, d). A rejected Q changes nothing (:meth:`step`)."""
        label, jump, far = self._next(Q, 2)
        X = self.op.branches[label].op(Q)  # may still raise (D(·, Q) not finite): the state is not yet changed
        if far:
            warn_far(far, 3)
        self._commit(label, jump)
        return X

    def run(self, Qs):
        """Follow a path Qs (k, n_moving, d): (labels (k,), X (k, n_vertices, d))."""
        Qs = opt.real_array("Qs", Qs)
        if Qs.ndim != 3:
            raise ValueError(f"Qs must have shape (k, {self.op.n_moving}, d), got {Qs.shape}")
        state = (self.branch, self.frame, list(self.jumps))
        try:  # one call: a rejected frame anywhere on the path changes nothing
            labels = np.empty(len(Qs), dtype=np.int64)
            for i, q in enumerate(Qs):  # a loop, not a comprehension (its own frame): the warnings' stacklevel
                labels[i] = self.step(q, _depth=2)
            return labels, self.op._on_branches(labels, Qs)
        except ValueError:
            self.branch, self.frame, self.jumps = state
            raise

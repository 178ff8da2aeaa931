"""The second design of handles that move at rest (:mod:`defop.operator.movable`): the nominal fixed-P operator
carried with the rest handles, :class:`CarryOp` (compared with the joint operator in ``benchmarks/bench_movable.py``).
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from . import core
from .movable import PLACEMENTS_KEPT, RestPlacement, correct


class CarryOp:
    """The second design: the nominal fixed-P operator, carried with the rest handles.

    A rest-space warp w_P(x) = x + Σ_ℓ g_{v_ℓ}(x) (p_ℓ⁰ − p_ℓ) (the placement bumps) takes each movable handle's
    vertex to its nominal position; the nominal operator D⁰ is evaluated with the same handle displacements,
    Q' = Q − P + P⁰, and its displacement field is read at w_P(x) (barycentric, in the rest mesh):
    D(x; P, Q) = x + u⁰(w_P(x); Q'), then the correction of (M). No joint training: one fixed-P operator.
    (8b) holds as for (M) (u⁰ = 0 at Q' = P⁰, and rest rows are x), Prop. 2 by the exact handle rows.

    Parameters
    ----------
    op0 : defop.operator.defop.DefOp
        Trained at the nominal placement.
    placement : defop.scene.placement.PlacementRegions
    """

    def __init__(self, op0, placement):
        self.op0, self.placement, self.mesh = op0, placement, op0.mesh
        self.handles, self.moving, self.d = op0.handles, op0.moving, op0.d
        self.n_vertices, self._placements = op0.n_vertices, core.KeptPlacements(PLACEMENTS_KEPT)

    def at(self, P=None):
        """The state of rest placement P: its vertices, the bumps, the barycentric map S of the rest-space warp
        and the shift of Q (checked and resolved once per placement, :class:`core.KeptPlacements`)."""
        return self._placements.get(P, None, self.placement.resolve, self._placement_state)

    def _placement_state(self, idx):
        import scipy.sparse as sp

        hm = self.placement.handles_at(idx)[self.moving]
        y, pl = self.mesh.V.copy(), self.placement
        g, rows, moved = pl.g, pl.bump_rows(idx), pl.members_at(idx)
        back = self.mesh.V[pl.members_at(pl.nominal)] - self.mesh.V[moved]  # (B, d): each member to its nominal
        for ell, row in enumerate(rows):
            a, b = g.indptr[row], g.indptr[row + 1]
            y[g.indices[a:b]] += g.data[a:b, None] * back[ell]
        elem, bary = self.mesh.locate(y)
        n = self.n_vertices
        S = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(n), self.d + 1), self.mesh.F[elem].ravel())), (n, n))
        return RestPlacement(
            idx=idx,
            hm=hm,
            P=self.mesh.V[hm],
            bumps=self.placement.bumps_at(idx),
            rows=self.placement.moved_rows(),
            moved=moved,
            S=S,
            shift=self.op0.P - self.mesh.V[hm],
        )

    def __call__(self, Q, P=None, fast=False):
        """D(·; P, Q) for Q (n, d) or (k, n, d) at one P; ``fast``: the nominal operator's fast path."""
        st = self.at(P)
        Q = opt.real_array("Q", Q)
        Qs = Q.reshape(-1, *st.P.shape)
        Qn = Qs + st.shift
        X0 = np.stack([self.op0.evaluate_fast(q) for q in Qn]) if fast else self.op0(Qn)
        u = np.stack([st.S @ (x - self.mesh.V) for x in X0]).reshape(len(Qs), -1)
        out = correct(self.mesh, self.placement, self.handles, self.moving, st, u, Qs)
        return out.reshape(*Q.shape[:-2], self.n_vertices, self.d)

"""Branch discovery: every verified minimum of problem (6) at the samples Q_k, grouped into branches (§5).

D^E is multi-valued where problem (6) has several local minima (the bar of Fig. 10 buckles up or down). The
single-valued training keeps one minimum per Q_k; here every verified minimum we can reach is kept, in five steps,
one module each:

1. :mod:`.grid`: the samples (a grid of one handle's displacements), their scans and neighbours;
2. :mod:`.discover`: at each Q_k the multi-start of the single-valued training plus the minima continuation sweeps
   reach (:func:`discover`);
3. :mod:`.group`: the minima grouped into branches by the side of the separating mode's score (:func:`group`), each
   with its stability margin (:mod:`.eigen`);
4. :mod:`.certify`: every sample bordering a branch's domain certified present or absent, the edge between them
   bisected towards the fold (:func:`certify_branches`);
5. :mod:`.fit`: one DefOp per branch with its energy and domain function (:func:`fit_branched`), or the
   single-valued fit (:func:`fit_single`).
"""

from __future__ import annotations

from ...lazy import renamed
from .certify import (
    FOLLOW_RATIO,
    Certified,
    bisect,
    bracket_fold,
    certify,
    certify_branches,
    is_certified,
    refine_segments,
)
from .discover import Minima, discover, solve_quietly, sweep
from .eigen import smallest_eigenpairs, stability_margin
from .fit import fit_branched, fit_single, values_at_train
from .grid import check_planar, grid_neighbours, grid_samples, grid_spacing, moving_set, neighbour_pairs, scan_order
from .group import (
    SampledBranch,
    SampledBranches,
    check_mesh,
    distinct_at,
    group,
    plane,
    score,
    separating_mode,
    threshold_plane,
)

__all__ = [
    "FOLLOW_RATIO",
    "Certified",
    "Minima",
    "SampledBranch",
    "SampledBranches",
    "bisect",
    "bracket_fold",
    "certify",
    "certify_branches",
    "check_mesh",
    "check_planar",
    "discover",
    "distinct_at",
    "fit_branched",
    "fit_single",
    "grid_neighbours",
    "grid_samples",
    "grid_spacing",
    "group",
    "is_certified",
    "moving_set",
    "neighbour_pairs",
    "plane",
    "refine_segments",
    "scan_order",
    "score",
    "separating_mode",
    "smallest_eigenpairs",
    "solve_quietly",
    "stability_margin",
    "sweep",
    "threshold_plane",
    "values_at_train",
]

#: old name -> new name: still served, with a DeprecationWarning
RENAMED = {"Branch": "SampledBranch", "Branches": "SampledBranches", "distinct_minima": "distinct_at"}

#: removed names -> what replaces them
REMOVED = {
    "refine_folds": "certify_branches(shape, branches, depth=...), which bisects every edge of each branch's domain "
    "and adds the edge minima (the λ² domain it fed is gone: fit_branched fits the certified domain)",
    "edge_of_branch": "bisect(step, lo, hi, X_lo, E_lo, depth) or bracket_fold(...)",
}


def removed(name):
    """A stand-in for a removed function: calling it raises NotImplementedError naming the replacement."""

    def gone(*args, **kwargs):
        raise NotImplementedError(f"defop.training.branches.{name} is removed: use {REMOVED[name]}")

    gone.__name__ = gone.__qualname__ = name
    return gone


_renamed = renamed(__name__, RENAMED, stacklevel=3)  # 3: through this module's __getattr__


def __getattr__(name):
    if name in REMOVED:
        return removed(name)
    return _renamed(name)

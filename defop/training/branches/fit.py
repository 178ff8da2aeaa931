"""Fitting the branches: one DefOp per branch with its energy and domain function, or the single-valued DefOp.

:func:`fit_branched` fits one DefOp per branch (:func:`defop.operator.fit.fit`, same bases and constraints: Prop. 2
everywhere, (8b) on every branch since the fit always includes the rest pose), E_b with the same Ψ
(:func:`defop.operator.fit.fit_values`) and the domain function g_b from the certified labels
(:func:`defop.operator.domains.fit_domain`: the signed distance to the branch's edge). :func:`fit_single` is the
single-valued fit to the lowest minimum per sample, for comparison.
"""

from __future__ import annotations

import numpy as np

from ...operator.branched import Branch as OperatorBranch
from ...operator.branched import BranchedOperator
from ...operator.domains import box_of, domain_values, fit_domain
from ...operator.fit import fit_shape, fit_values
from .certify import is_certified
from .grid import grid_spacing
from .group import check_mesh

__all__ = ["fit_branched", "fit_single", "values_at_train"]


def values_at_train(op, branch_values, rest_value, samples):
    """Values aligned with ``op.train_samples``: the rest pose's first, then the samples' (those at rest dropped, as
    :func:`defop.operator.fit.fit` drops them)."""
    at_rest = np.abs(samples - op.P).reshape(len(samples), -1).max(axis=1) <= 1e-14
    return np.concatenate([[rest_value], np.asarray(branch_values, float)[~at_rest]])


def fit_branched(shape, branches, energy="sarap", basis="tps", spatial="hat", k=100, **kw):
    """One DefOp per branch (problem (8) on its samples) with E_b and the domain function g_b: a BranchedOperator.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    branches : defop.training.branches.SampledBranches
        Certified (:func:`defop.training.branches.certify_branches`): the domains are fitted from its labels.
    energy : str
        The energy the minima minimise (the metadata).
    basis, spatial, k, **kw
        As :func:`defop.operator.fit.fit`.

    Returns
    -------
    defop.operator.branched.BranchedOperator
    """
    check_mesh(shape, branches)
    if not is_certified(branches):
        raise ValueError(
            "branches must be certified: pass them through defop.training.branches.certify_branches(shape, branches) "
            "first (each branch's domain is fitted from its certified presence and absence)"
        )
    out = []
    user_meta = kw.pop("meta", None) or {}  # every branch's operator carries the caller's meta
    grid = branches.samples[: branches.grid]
    for b in branches.branches:
        Q = branches.samples[b.samples]
        meta = {"energy": energy, "branch": b.label, **user_meta}
        op = fit_shape(shape, Q, b.X, basis, spatial, k, meta=meta, **kw)
        e = fit_values(op, values_at_train(op, b.energy, 0.0, Q))
        points, values = domain_values(grid, b.samples[b.samples < len(grid)], b.folds, b.segments)
        domain = fit_domain(op.P, op.handle_basis.scale, points, values)
        out.append(OperatorBranch(b.label, op, e, None, b.side, domain=domain))
    meta = {"shape": shape.name, "energy": energy, "conflicts": branches.conflicts}
    box = box_of(shape.P_moving, grid, grid_spacing(grid))
    return BranchedOperator(out, branches.mode, branches.threshold, meta, box=box)


def fit_single(shape, minima, energy="sarap", basis="tps", spatial="hat", k=100):
    """The single-valued fit: problem (8) on the lowest verified minimum at each sample (the training of today)."""
    E = np.where(minima.converged, minima.energy, np.inf)
    ok = np.isfinite(E).any(axis=1)
    c = np.argmin(E, axis=1)
    ks = np.flatnonzero(ok)
    return fit_shape(shape, minima.samples[ks], minima.X[ks, c[ks]], basis, spatial, k, meta={"energy": energy})

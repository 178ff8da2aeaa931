"""Certification's results as flat arrays: the cache entry of :func:`defop.training.branches.certify`.

Each branch i's :class:`defop.training.branches.Certified` becomes arrays named ``b{i}.<field>`` (the present samples
sorted, with their minima and energies; the absent and uncertified samples; the fold points and their grid edges;
the inner fold points; the segments; the edge minima; the counts), and back. The key holds everything that decides
the result: the mesh, the handles, the grid samples, every branch's minima and side, the mode, the threshold, the
bisection depth, the grouping tolerance and the solver's settings.
"""

from __future__ import annotations

import numpy as np

from .. import cache as cache_mod

__all__ = ["certified_key", "expected", "from_arrays", "to_arrays"]


def certified_key(shape, branches, grid, depth, tol, solver):
    """The cache key of certifying ``branches`` (their first ``grid`` samples) on ``shape``."""
    parts = [shape.mesh.V, shape.mesh.F, np.asarray(shape.handles), np.asarray(shape.moving)]
    parts += [np.asarray(branches.samples)[:grid], np.asarray(branches.mode), np.asarray(branches.threshold)]
    for b in branches.branches:
        parts += [np.asarray(b.samples), np.asarray(b.X), np.asarray(b.energy), int(b.side)]
    return cache_mod.key("branch-certified", *parts, int(depth), float(tol), cache_mod.solver_settings(solver))


def expected(n_branches, qshape, xshape):
    """``expect`` of :func:`defop.training.batch.load_or_compute` for ``n_branches`` branches."""
    out = {"seconds": ((1,), "f")}
    for i in range(n_branches):
        p = f"b{i}."
        out |= {
            p + "present": ((None,), "i"),
            p + "present_X": ((None, *xshape), "f"),
            p + "present_E": ((None,), "f"),
            p + "absent": ((None,), "i"),
            p + "uncertified": ((None,), "i"),
            p + "folds": ((None, *qshape), "f"),
            p + "fold_edges": ((None, 2), "i"),
            p + "folds_inner": ((None, *qshape), "f"),
            p + "segments": ((None, 2, *qshape), "f"),
            p + "edges_Q": ((None, *qshape), "f"),
            p + "edges_X": ((None, *xshape), "f"),
            p + "edges_E": ((None,), "f"),
            p + "counts": ((1,), "i"),
            p + "third": ((None,), "i"),
        }
    return out


def to_arrays(certified, seconds, qshape, xshape):
    """The arrays of :func:`expected` for a list of Certified and their CPU seconds."""
    out = {"seconds": np.array([seconds], dtype=float)}
    for i, c in enumerate(certified):
        p, ks = f"b{i}.", sorted(c.present)
        out |= {
            p + "present": np.array(ks, dtype=np.int64),
            p + "present_X": np.array([c.present[k][0] for k in ks], dtype=float).reshape(-1, *xshape),
            p + "present_E": np.array([c.present[k][1] for k in ks], dtype=float),
            p + "absent": np.array(c.absent, dtype=np.int64),
            p + "uncertified": np.array(c.uncertified, dtype=np.int64),
            p + "folds": np.array(c.folds, dtype=float).reshape(-1, *qshape),
            p + "fold_edges": np.array(c.fold_edges, dtype=np.int64).reshape(-1, 2),
            p + "folds_inner": np.array(c.folds_inner, dtype=float).reshape(-1, *qshape),
            p + "segments": np.asarray(c.segments, dtype=float).reshape(-1, 2, *qshape),
            p + "edges_Q": np.array([e[0] for e in c.edges], dtype=float).reshape(-1, *qshape),
            p + "edges_X": np.array([e[1] for e in c.edges], dtype=float).reshape(-1, *xshape),
            p + "edges_E": np.array([e[2] for e in c.edges], dtype=float),
            p + "counts": np.array([c.found], dtype=np.int64),
            p + "third": np.array(c.third, dtype=np.int64),
        }
    return out


def from_arrays(z, n_branches, make):
    """(list of Certified, seconds) from the arrays of :func:`to_arrays`; ``make`` is the Certified class."""
    out = []
    for i in range(n_branches):
        p = f"b{i}."
        present = {int(k): (X, float(E)) for k, X, E in zip(z[p + "present"], z[p + "present_X"], z[p + "present_E"])}
        edges = [(q, X, float(E)) for q, X, E in zip(z[p + "edges_Q"], z[p + "edges_X"], z[p + "edges_E"])]
        out.append(
            make(
                present,
                absent=z[p + "absent"].tolist(),
                uncertified=z[p + "uncertified"].tolist(),
                folds=list(z[p + "folds"]),
                fold_edges=[tuple(e) for e in z[p + "fold_edges"].tolist()],
                folds_inner=list(z[p + "folds_inner"]),
                segments=z[p + "segments"],
                edges=edges,
                found=int(z[p + "counts"][0]),
                third=z[p + "third"].tolist(),
            )
        )
    return out, float(z["seconds"][0])

"""Certification on inputs a user repeats or mixes up: certifying certified branches changes nothing, ``edges=False``
and a grid holding one branch work, branches grouped on another mesh are refused by name; the old names warn.

The bar of Fig. 10 on 200 vertices and 9 × 9 samples (the fixture of tests/test_branches_domains.py).
"""

import dataclasses
import warnings

import numpy as np
import pytest
from test_branches_domains import certified

import defop as dop
from defop.training import branches as br


def same(a, b):
    """Every field of two SampledBranches (and of their branches) equal, arrays bit for bit."""
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "branches":
            assert len(x) == len(y)
            for bx, by in zip(x, y):
                for g in dataclasses.fields(bx):
                    u, v = getattr(bx, g.name), getattr(by, g.name)
                    assert np.array_equal(u, v, equal_nan=True), (f.name, g.name)
        else:
            assert np.array_equal(x, y, equal_nan=True), f.name


def test_certifying_certified_branches_changes_nothing():
    shape, Q, _, B, C, bop = certified()
    again = br.certify_branches(shape, C, depth=3)
    same(again, C)
    assert np.array_equal(br.fit_branched(shape, again).exists(Q), bop.exists(Q))


def test_edges_false_keeps_the_grid_labels():
    shape, Q, _, B, C, _ = certified()
    D = br.certify_branches(shape, B, depth=3, edges=False)
    assert D.grid == len(Q) and len(D.samples) == len(Q)  # no edge minima
    for b, c in zip(D.branches, C.branches):
        assert np.array_equal(b.samples, c.samples[c.samples < C.grid])
        assert np.array_equal(b.absent, c.absent) and np.array_equal(b.folds, c.folds)
    bop = br.fit_branched(shape, D)
    for b in D.branches:
        assert bop.exists(Q[b.samples])[:, b.label].all()


def test_one_branch_grid_certifies_and_fits():
    shape = dop.shapes.load("bar", 200)
    Q = br.grid_samples(shape, 0.05, 3)  # small moves: one minimum everywhere
    B = br.group(shape, br.discover(shape, Q, [br.scan_order(3, 3)]), margins=False)
    for edges in (True, False):
        C = br.certify_branches(shape, B, edges=edges)
        assert len(C.branches) == 1 and len(C.branches[0].samples) == len(Q) and len(C.branches[0].absent) == 0
        bop = br.fit_branched(shape, C)
        assert bop.exists(Q).all() and np.array_equal(bop(shape.P_moving), shape.mesh.V)


def test_branches_of_another_mesh_are_refused_by_name():
    shape, _, _, B, C, _ = certified()
    other = dop.shapes.load("bar")  # the same shape on its default mesh
    assert other.mesh.n_vertices != shape.mesh.n_vertices
    for call in (
        lambda: br.certify_branches(other, B),
        lambda: br.certify_branches(other, C),
        lambda: br.certify(other, B),
        lambda: br.fit_branched(other, C),
    ):
        with pytest.raises(ValueError, match=r"mesh of \d+ vertices.*grouped on"):
            call()


def test_uncertified_branches_are_not_fitted():
    shape, _, _, B, _, _ = certified()
    with pytest.raises(ValueError, match="certify_branches"):
        br.fit_branched(shape, B)


def test_old_names_warn_and_still_work():
    shape, Q, _, B, C, _ = certified()
    with pytest.warns(DeprecationWarning, match="SampledBranches"):
        assert br.Branches is br.SampledBranches
    with pytest.warns(DeprecationWarning, match="SampledBranch"):
        assert br.Branch is br.SampledBranch
    with pytest.warns(DeprecationWarning, match="depth="):
        again = br.certify_branches(shape, C, levels=3)
    assert again is C
    with pytest.raises(NotImplementedError, match="certify_branches"):
        br.refine_folds(shape, B, levels=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from defop.training import branch_domains as bd
    assert bd.certify_branches is br.certify_branches
    with pytest.raises(TypeError, match="depth= only"):
        br.certify_branches(shape, B, depth=3, levels=3)


def test_certification_is_cached_and_the_cached_result_is_the_same(tmp_path, monkeypatch):
    shape, Q, _, B, C, _ = certified()
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    first = br.certify_branches(shape, B, depth=3, n_jobs=1)
    assert len(list(tmp_path.glob("branch-certified-*.npz"))) == 1
    again = br.certify_branches(shape, B, depth=3)  # loaded: the same labels, minima and measured seconds
    same(again, first)
    for a, c in zip(first.branches, C.branches):  # and the same as the fixture's (computed with every worker)
        assert np.array_equal(a.samples, c.samples) and np.array_equal(a.absent, c.absent)
        assert np.abs(a.X - c.X).max() < 1e-12 and np.abs(a.folds - c.folds).max() < 1e-12


def test_minima_of_another_mesh_are_not_grouped():
    shape, _, minima, _, _, _ = certified()
    with pytest.raises(ValueError, match="another mesh"):
        br.group(dop.shapes.load("bar"), minima)

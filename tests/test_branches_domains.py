"""Branches on shapes nobody tuned for: certified presence and absence, the domain fitted from both
sides, the far-Q warning, files of both versions, and a random bistable case.

The bar of Fig. 10 on 200 vertices and 9 × 9 samples of its end handle (±0.3), one continuation sweep, then
:func:`defop.training.branches.certify_branches` (bisection depth 3): ``exists_b`` agrees with every certified
label, and past each fold point it does not claim the branch; every branch path warns outside the samples' box
enlarged by one spacing (and its warning names the caller's line); version-1 files (λ²_b as the domain, built by
hand) still load.
The random case: the first accepted seed of :mod:`defop.analysis.random_branches` on 120 vertices, 13 × 13 samples
and a path of 40 steps each way: ``follow`` jumps where the solver's continuation jumps, within 1 step (on 9 × 9
samples it jumps 2 steps early on the way out: that path runs almost along the fold, where a fold point's error
of 2^−3 of a spacing across the fold moves the crossing by several steps).
"""

import functools
import json
import warnings

import numpy as np
import pytest

import defop as dop
from defop.analysis import random_branches as rb
from defop.operator import ExtrapolationWarning
from defop.operator.branched import Branch as OperatorBranch
from defop.operator.branched import BranchedOperator
from defop.operator.fit import fit_shape, fit_values
from defop.training import branches as br

N, R = 9, 0.3


@functools.cache
def certified():
    shape = dop.shapes.load("bar", 200)
    Q = br.grid_samples(shape, R, N)
    minima = br.discover(shape, Q, [br.scan_order(N, N)])
    B = br.group(shape, minima, margins=False)
    C = br.certify_branches(shape, B, depth=3)
    return shape, Q, minima, B, C, br.fit_branched(shape, C)


def quiet(f, *a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a, **kw)


def test_exists_agrees_with_every_certified_label():
    shape, Q, _, B, C, bop = certified()
    assert C.grid == N * N and len(C.branches) == 2
    ex = quiet(bop.exists, Q)
    for b in C.branches:
        present = b.samples[b.samples < C.grid]
        assert len(b.absent) > 0 and len(b.folds) > 0  # each branch's domain ends inside the grid
        assert not set(present.tolist()) & set(b.absent.tolist())
        assert ex[present, b.label].all()  # present: exists
        assert not ex[b.absent, b.label].any()  # certified absent: does not
    # every sample that discovery put on a branch stays on it (certification only adds)
    for b0, b1 in zip(B.branches, C.branches):
        assert set(b0.samples.tolist()) <= set(b1.samples.tolist())
    assert C.certify_seconds > 0


def test_a_margin_past_the_fold_does_not_claim_the_branch():
    shape, Q, _, B, C, bop = certified()
    flat = Q.reshape(len(Q), -1)
    beyond, inside = [], []
    for b in C.branches:
        present = b.samples[b.samples < C.grid]
        for f in b.folds.reshape(len(b.folds), -1):
            d = np.linalg.norm(flat - f, axis=1)
            j = b.absent[np.argmin(d[b.absent])]  # the absent sample the fold point was bisected towards
            k = present[np.argmin(d[present])]
            beyond.append((b.label, (0.75 * Q[j] + 0.25 * f.reshape(Q.shape[1:]))))
            inside.append((b.label, (0.75 * Q[k] + 0.25 * f.reshape(Q.shape[1:]))))
    ex_out = quiet(bop.exists, np.array([q for _, q in beyond]))
    ex_in = quiet(bop.exists, np.array([q for _, q in inside]))
    labels = np.array([b for b, _ in beyond])
    assert not ex_out[np.arange(len(labels)), labels].any()  # past every fold point: not claimed
    assert ex_in[np.arange(len(labels)), labels].mean() >= 0.9  # and before it, claimed


def _minima():
    return certified()[2]


def lambda_operator(shape, B, energy="sarap"):
    """The format-1 model (built by hand: the training no longer fits it): each branch's domain is λ²_b, its
    stability margin squared, fitted on its own samples with the rest pose's λ_min²."""
    solver = dop.variational.solver.Solver(shape.mesh, shape.handles, energy=energy)
    lam_rest = br.stability_margin(solver, shape.mesh.V, B.mode)
    out = []
    for b in B.branches:
        Q = B.samples[b.samples]
        op = fit_shape(shape, Q, b.X, "tps", "hat", 100, meta={"energy": energy, "branch": b.label})
        e = fit_values(op, br.values_at_train(op, b.energy, 0.0, Q))
        lam = fit_values(op, br.values_at_train(op, b.margin**2, lam_rest**2, Q))
        out.append(OperatorBranch(b.label, op, e, lam, b.side))
    return BranchedOperator(out, B.mode, B.threshold, {"shape": shape.name, "energy": energy, "conflicts": 0})


def _paths(bop, Q):
    """Every branch path, evaluated at one Q (and a batch of it)."""
    Qs = np.stack([Q, Q])
    return {
        "global": lambda: bop(Q),
        "global batch": lambda: bop(Qs),
        "branch": lambda: bop(Q, branch=1),
        "choose": lambda: bop.choose(Q),
        "exists": lambda: bop.exists(Q),
        "estimates": lambda: bop.estimates(Q),
        "on_branches": lambda: bop.on_branches([0, 1], Qs),
        "step": lambda: bop.session(0).step(Q),
        "session": lambda: bop.session(1)(Q),
        "run": lambda: bop.session().run(Qs),
    }


@pytest.mark.parametrize("where", ["x", "y", "both"])
def test_far_q_warns_on_every_branch_path(where):
    shape, Q, _, _, C, bop = certified()
    h = br.grid_spacing(Q)
    far = shape.P_moving.copy()
    off = {"x": (1, 0), "y": (0, 1), "both": (-1, -1)}[where]
    far[0] += (R + 1.05 * h) * np.array(off)  # just outside the box enlarged by one spacing
    near = shape.P_moving + (R + 0.95 * h) * np.array(off)  # just inside: no box warning
    for name, call in _paths(bop, far).items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            call()
        box = [w for w in caught if issubclass(w.category, ExtrapolationWarning) and "box" in str(w.message)]
        assert box, name
        assert all(w.filename == __file__ for w in box), (name, [w.filename for w in box])  # the caller's line
    for name, call in _paths(bop, near).items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            call()
        assert not [w for w in caught if "box" in str(w.message)], name


def test_files_version_2_round_trip_and_version_1_loads(tmp_path):
    shape, Q, _, _, C, bop = certified()
    bop.save(tmp_path / "v2.npz")
    back = BranchedOperator.load(tmp_path / "v2.npz")
    assert np.array_equal(back.box, bop.box)
    for a, b in zip(back.branches, bop.branches):
        assert a.domain.own and np.array_equal(a.domain.w, b.domain.w)
    assert np.array_equal(quiet(back.exists, Q), quiet(bop.exists, Q))
    assert np.array_equal(quiet(back, Q), quiet(bop, Q))
    # a version-1 file (λ²_b on Ψ_b, no box) loads with its λ²_b as the domain
    old = lambda_operator(shape, br.group(shape, _minima(), margins=True))
    old.save(tmp_path / "old.npz")
    _as_version_1(tmp_path / "old.npz", tmp_path / "v1.npz")
    v1 = BranchedOperator.load(tmp_path / "v1.npz")
    assert all(not b.domain.own for b in v1.branches)
    assert np.array_equal(quiet(v1.exists, Q), quiet(old.exists, Q))
    # a version-2 header whose domain entry is broken: a clear error naming the file
    _edit_header(tmp_path / "v2.npz", tmp_path / "bad.npz", lambda h: h["branches"][1].update(domain="x"))
    with pytest.raises(ValueError, match=r"bad\.npz.*domain"):
        BranchedOperator.load(tmp_path / "bad.npz")


def _edit_header(src, dst, edit, drop=()):
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    header = json.loads(str(arrays["header"]))
    edit(header)
    arrays["header"] = np.array(json.dumps(header))
    with open(dst, "wb") as fh:
        np.savez(fh, **arrays)


def _as_version_1(src, dst):
    def edit(h):
        h["format"], h["format_version"] = "defop-branched-1", 1
        for e in h["branches"]:
            e.pop("domain")

    with np.load(src) as z:
        drop = ["box"] + [k for k in z.files if k.endswith(".domain_w")]
    _edit_header(src, dst, edit, drop)


def test_more_than_two_minima_are_reported():
    shape, Q, _, B, C, _ = certified()
    assert C.third.dtype.kind == "i" and set(B.third.tolist()) <= set(C.third.tolist())
    assert np.array_equal(B.third, np.flatnonzero(B.distinct > 2))


def test_certify_refuses_several_independent_handles():
    shape = dop.shapes.load("u_shape", 200)  # two moving tips, moved independently: a 4D space of Q
    Q = shape.P_moving + np.random.default_rng(0).uniform(-0.1, 0.1, (12, *shape.P_moving.shape))
    m = len(Q)
    B = br.SampledBranches(Q, [], np.zeros_like(shape.mesh.V), np.zeros(5), np.ones(m, int), 0, np.zeros(m, int))
    with pytest.raises(ValueError, match="one moving handle"):
        br.certify(shape, B)


@functools.cache
def random_case():
    ((case, truth),) = rb.random_cases(1, vertices=120, steps=40, log=lambda line: None)
    return case, truth, rb.run_random(case, truth, n=13, steps=40)


def test_a_random_bistable_case_follow_reproduces_the_solvers_loop():
    case, truth, run = random_case()
    c = run.comparison
    js, jf = c.jumps["solver"], c.jumps["follow"]
    assert len(js) == 2 and js[0] <= 40 < js[1]  # accepted: the solver jumps once each way
    assert len(jf) == 2 and np.abs(jf - js).max() <= 1, (js, jf)  # follow too, within 1 step
    assert c.follow[~c.near].mean() <= 1.5 * c.single[~c.near].mean()

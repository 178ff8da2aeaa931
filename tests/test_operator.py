"""DefOp: batch evaluation, compression, save/load round trip, bad input and extrapolation warnings."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.operator import handle_bases as hb
from defop.operator.defop import DefOp, ExtrapolationWarning


@pytest.fixture(scope="module")
def op_and_data():
    s = dop.shapes.load("bar", n_vertices=250)
    solver = dop.variational.Solver(s.mesh, s.handles, "arap")
    Q = dop.training.sampling.sample_shape(s, 25, np.random.default_rng(0))
    X = np.array([solver.solve(s.targets(q)).X for q in Q])
    return s, dop.operator.fit.fit_shape(s, Q, X, "tps", meta={"energy": "arap"}), Q, X


def test_single_and_batch_agree(op_and_data):
    s, op, Q, _ = op_and_data
    batch = op(Q[:5])
    assert batch.shape == (5, s.mesh.n_vertices, 2)
    assert np.allclose(batch[2], op(Q[2])) and np.allclose(op.evaluate_fast(Q[2]), op(Q[2]))


def test_compression_is_controlled(op_and_data):
    s, op, Q, X = op_and_data
    exact = op(Q)
    op.compress(tol=1e-6)
    try:
        assert op.rank < op.handle_basis.size
        assert np.abs(op(Q) - exact).max() <= 1e-5 * s.mesh.bbox_diagonal
    finally:
        op.decompress()
    assert np.array_equal(op(Q), exact)


def test_compressed_factors_are_float32_and_results_float64(op_and_data, tmp_path):
    s, op, Q, _ = op_and_data
    exact = op(Q[:3])
    op.compress(tol=1e-6)
    try:
        assert all(f.dtype == np.float32 for f in op.factors)
        fast, batch = op.evaluate_fast(Q[1]), op(Q[:3])
        assert fast.dtype == batch.dtype == np.float64
        assert np.allclose(fast, batch[1], rtol=0, atol=1e-6 * s.mesh.bbox_diagonal)
        assert np.abs(batch - exact).max() <= 1e-5 * s.mesh.bbox_diagonal
        op.save(tmp_path / "c.npz")
        back = DefOp.load(tmp_path / "c.npz")
        assert back.factors[1].dtype == np.float32 and np.array_equal(back(Q[:3]), batch)
    finally:
        op.decompress()


def test_save_load_round_trip(op_and_data, tmp_path):
    s, op, Q, _ = op_and_data
    op.save(tmp_path / "op.npz")
    back = DefOp.load(tmp_path / "op.npz")
    assert np.array_equal(back(Q), op(Q))
    assert back.meta == op.meta and back.meta["shape"] == "bar" and back.meta["energy"] == "arap"
    assert back.meta["basis"] == "tps" and back.meta["n_samples"] == 25 and "version" in back.meta
    back.check_mesh(s.mesh)


def test_corrupt_and_incompatible_files(op_and_data, tmp_path):
    _, op, _, _ = op_and_data
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match=r"junk.npz is not a defop operator file \(not a zip archive\)"):
        DefOp.load(junk)
    np.savez(tmp_path / "other.npz", header=np.array('{"format": "something-else"}'))
    with pytest.raises(ValueError, match="has format 'something-else'"):
        DefOp.load(tmp_path / "other.npz")
    with pytest.raises(ValueError, match="no such operator file"):
        DefOp.load(tmp_path / "missing.npz")


def test_bad_Q_and_other_mesh(op_and_data):
    s, op, _, _ = op_and_data
    with pytest.raises(ValueError, match=r"Q must have shape \(1, 2\)"):
        op(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        op(np.array([[np.nan, 0.0]]))
    other = dop.shapes.load("bar", n_vertices=300).mesh
    with pytest.raises(ValueError, match="trained on a mesh with"):
        op.check_mesh(other)


def test_extrapolation_warning(op_and_data):
    s, op, _, _ = op_and_data
    with pytest.warns(ExtrapolationWarning, match="moving handle 0 .* extrapolates"):
        op(s.P_moving + [[3.0, 0.0]])


# ---------------------------------------------------------------- the guarantees on every path (issue 15)
# Prop. 2 (handles interpolated) and (8b) (D(x, P) = x) must hold by construction for any fitted data,
# so the data below is synthetic: random handle subsets, random samples, a random smooth deformation.

_MESH = {}


def _mesh():
    if "bar" not in _MESH:
        _MESH["bar"] = dop.shapes.load("bar", n_vertices=250).mesh
    return _MESH["bar"]


def _random_operator(seed, basis, spatial, n_handles, n_moving):
    rng = np.random.default_rng(seed)
    mesh = _mesh()
    handles = rng.choice(mesh.n_vertices, n_handles, replace=False)
    moving = np.zeros(n_handles, bool)
    moving[rng.choice(n_handles, n_moving, replace=False)] = True
    P = mesh.V[handles[moving]]
    q = hb.basis_size(basis, n_moving, 0 if basis != "tps" else 1)
    m = max(q + 4, 2 * n_moving + 8)
    Q = P + 0.2 * rng.standard_normal((m, n_moving, 2))
    # a smooth synthetic "ground truth": any data must give the guarantees
    a = rng.standard_normal((m, 2, 2)) * 0.3
    X = mesh.V + np.einsum("mij,vj->mvi", a, mesh.V) + 0.05 * np.sin(3 * mesh.V[None, :, :1] + Q[:, :1, :1])
    return dop.operator.fit.fit(mesh, handles, moving, Q, X, basis, spatial, k=12), Q


def _paths(op, Qs):
    """Every evaluation path on Qs (k,n,2): (name, (k,n_vertices,2))."""
    return [
        ("op(Q)", np.array([op(q) for q in Qs])),
        ("op(Qs)", op(Qs)),
        ("evaluate_fast", np.array([op.evaluate_fast(q) for q in Qs])),
        ("evaluate_batch", op.evaluate_batch(Qs)),
    ]


def _assert_guarantees(op, Qs, where):
    diag = op.mesh.bbox_diagonal
    hv = op.handles[op.moving]
    fixed = op.handles[~op.moving]
    for name, D in _paths(op, Qs):
        # Prop. 2: moving handles follow Q, fixed handles stay, to 1e-9 of the diagonal (+ round-off of |Q|)
        tol = 1e-9 * diag + 4e-16 * np.abs(Qs).max(axis=(1, 2))[:, None, None]
        assert np.all(np.abs(D[:, hv] - Qs) <= tol), f"{where}, {name}: handles off by {np.abs(D[:, hv] - Qs).max()}"
        assert np.array_equal(D[:, fixed], np.broadcast_to(op.mesh.V[fixed], D[:, fixed].shape)), name
    for name, D in _paths(op, op.P[None]):
        # (8b): the rest pose is reproduced exactly (δψ(P) = 0 bit for bit)
        assert np.abs(D[0] - op.mesh.V).max() <= 1e-9 * diag, f"{where}, {name}: rest pose off"


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    basis=st.sampled_from(["linear", "quadratic", "tps"]),
    spatial=st.sampled_from(["hat", "reduced"]),
    n_handles=st.integers(1, 5),
    data=st.data(),
)
def test_handles_and_rest_pose_exact_on_every_path(seed, basis, spatial, n_handles, data):
    n_moving = data.draw(st.integers(1, min(n_handles, 3)), label="n_moving")
    if basis == "quadratic" and n_moving > 2:
        n_moving = 2
    op, Q = _random_operator(seed, basis, spatial, n_handles, n_moving)
    rng = np.random.default_rng(seed + 1)
    far = data.draw(st.sampled_from([0.1, 1.0, 30.0, 1e4]), label="distance / diagonal")
    Qs = op.P + far * op.mesh.bbox_diagonal * rng.standard_normal((4, n_moving, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        _assert_guarantees(op, Qs, "exact W")
        for rank, dtype in [(1, np.float32), (3, np.float32), (None, np.float64)]:
            op.compress(rank=rank, tol=1e-2, dtype=dtype)
            _assert_guarantees(op, Qs, f"rank {op.rank} {np.dtype(dtype).name}")
        op.decompress()


def test_batch_api_matches_single_frames(op_and_data):
    s, op, Q, _ = op_and_data
    exact = op(Q)
    fast = op.evaluate_batch(Q)
    assert fast.shape == exact.shape and fast.dtype == np.float64
    assert np.abs(fast - exact).max() <= 1e-5 * s.mesh.bbox_diagonal  # float32 W_F
    single = np.array([op.evaluate_fast(q) for q in Q])
    assert np.abs(single - fast).max() <= 1e-5 * s.mesh.bbox_diagonal
    with pytest.raises(ValueError, match=r"Qs must have shape \(k, 1, 2\)"):
        op.evaluate_batch(Q[0])


def test_compression_discards_at_most_tol_of_the_training_displacements(op_and_data):
    # the TPS operator reproduces the training set (Prop. 1), so on it the compressed operator's (8a) error is
    # exactly the discarded part of the mass-weighted displacements Y, which compress() bounds by tol ‖Y‖
    s, op, Q, X = op_and_data
    mass = s.mesh.mass_matrix.diagonal()
    total = np.einsum("v,kvc->", mass, (X - s.mesh.V) ** 2)
    for tol in (1e-1, 1e-2, 1e-3):
        op.compress(tol=tol, dtype=np.float64)
        try:
            discarded = dop.analysis.approximation_error(op, Q, X) * s.mesh.n_vertices
            assert discarded <= tol**2 * total * (1 + 1e-6)
            assert np.all(op.factors[1][:, op._all_hcols] == 0)  # B never touches the handle columns
        finally:
            op.decompress()


# ---------------------------------------------------------------- never NaN, clear errors (issue 14)
@pytest.mark.parametrize("path", ["call", "batch", "fast"])
def test_non_finite_psi_raises_naming_Q(op_and_data, path):
    s, op, _, _ = op_and_data
    far = s.P_moving + 1e200
    f = {"call": op, "batch": lambda q: op.evaluate_batch(q[None]), "fast": op.evaluate_fast}[path]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # the error alone: no overflow warning before it
        warnings.simplefilter("ignore", ExtrapolationWarning)
        with pytest.raises(ValueError, match=r"Ψ\(Q\) is not finite at Q = \[\[1\.e\+200"):
            f(far)


def test_evaluate_fast_rejects_nan(op_and_data):
    s, op, _, _ = op_and_data
    for compressed in (False, True):
        if compressed:
            op.compress(rank=3)
        try:
            with pytest.raises(ValueError, match=r"Q has NaN or infinite entries \(first at \[0, 0\]\)"):
                op.evaluate_fast(np.array([[np.nan, 0.0]]))
        finally:
            op.decompress()


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"tol": -1}, r"tol must be a relative tolerance in \[0, 1\), got -1"),
        ({"tol": float("nan")}, r"tol must be a relative tolerance in \[0, 1\), got nan"),
        ({"tol": 1.5}, r"tol must be a relative tolerance in \[0, 1\), got 1.5"),
        ({"rank": 0}, "rank must be a positive integer, got 0"),
        ({"rank": 2.5}, "rank must be a positive integer, got 2.5"),
        ({"rank": True}, "rank must be a positive integer, got True"),
        ({"rank": 3, "dtype": np.int32}, "dtype must be float32 or float64, got int32"),
    ],
)
def test_compress_validates_its_options(op_and_data, kw, message):
    _, op, _, _ = op_and_data
    with pytest.raises(ValueError, match=message):
        op.compress(**kw)
    assert op.factors is None


def _rewrite(src, dst, header=None, **arrays):
    with np.load(src) as z:
        data = {k: z[k] for k in z.files}
    if header is not None:
        data["header"] = np.array(json.dumps(header))
    data.update(arrays)
    with open(dst, "wb") as fh:
        np.savez(fh, **data)
    return dst


@pytest.mark.parametrize(
    "drop, message",
    [("meta", "'meta'"), ("basis", "'basis'"), ("kind", "'kind'"), ("scale", "'scale'")],
)
def test_load_header_missing_keys_is_a_value_error(op_and_data, tmp_path, drop, message):
    _, op, _, _ = op_and_data
    op.save(tmp_path / "op.npz")
    with np.load(tmp_path / "op.npz") as z:
        header = json.loads(str(z["header"]))
    if drop in header:
        del header[drop]
    else:
        del header["basis"][drop]
    bad = _rewrite(tmp_path / "op.npz", tmp_path / "bad.npz", header)
    with pytest.raises(ValueError, match=f"not a valid defop operator file: missing {message}"):
        DefOp.load(bad)


@pytest.mark.parametrize(
    "name, make, message",
    [
        ("W", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 7, np.nan, a), "'W' has NaN or infinite"),
        ("W", lambda a: a[:, :-2], r"'W' has shape \(\d+, \d+\), expected"),
        ("V", lambda a: np.where(a == a[0, 0], np.inf, a), "'V' has NaN or infinite"),
        ("F", lambda a: a[:, :2], r"'F' has shape \(\d+, 2\), expected \(None, 3\)"),
        ("basis_centers", lambda a: a * np.nan, "'basis_centers' has NaN"),
        ("train_samples", lambda a: a[..., :1], r"'train_samples' has shape"),
        ("handles", lambda a: a + 10**6, r"handle indices must lie in \[0, \d+\)"),
        ("moving", lambda a: a.astype(float), "'moving' must be 1-D of kind 'b'"),
        ("basis_P", lambda a: a + 1.0, "basis_P is not the rest position of the moving handles"),
    ],
)
def test_load_checks_every_array(op_and_data, tmp_path, name, make, message):
    _, op, _, _ = op_and_data
    op.save(tmp_path / "op.npz")
    with np.load(tmp_path / "op.npz") as z:
        bad_array = make(z[name])
    bad = _rewrite(tmp_path / "op.npz", tmp_path / "bad.npz", **{name: bad_array})
    with pytest.raises(ValueError, match=message):
        DefOp.load(bad)


def test_load_checks_the_factors(op_and_data, tmp_path):
    _, op, Q, _ = op_and_data
    op.compress(rank=3)
    try:
        op.save(tmp_path / "c.npz")
        back = DefOp.load(tmp_path / "c.npz")
        assert np.array_equal(back(Q), op(Q)) and back.rank == 3
        A, B = op.factors
        touched = B.copy()
        touched[:, op._all_hcols[0]] = 1.0
        for arrays, message in [
            ({"factor_B": touched}, "factor_B must be zero on the handle columns"),
            ({"factor_A": A[:-1]}, r"'factor_A' has shape"),
            ({"factor_A": A * np.nan}, "'factor_A' has NaN"),
        ]:
            bad = _rewrite(tmp_path / "c.npz", tmp_path / "bad.npz", **arrays)
            with pytest.raises(ValueError, match=message):
                DefOp.load(bad)
    finally:
        op.decompress()


def test_evaluate_batch_into_out(op_and_data):
    s, op, Q, _ = op_and_data
    buf = np.full((len(Q), s.mesh.n_vertices, 2), np.nan)
    assert op.evaluate_batch(Q, out=buf) is buf
    assert np.array_equal(buf, op.evaluate_batch(Q))
    with pytest.raises(ValueError, match="out must be a C-contiguous float64 array of shape"):
        op.evaluate_batch(Q, out=buf[:-1])


def test_format_1_files_still_load(op_and_data, tmp_path):
    # operators cached before (★): format 1, W only, or W with factors of Ψ W (|Ψ| rows), which are rebuilt
    _, op, Q, _ = op_and_data
    op.save(tmp_path / "op.npz")
    with np.load(tmp_path / "op.npz") as z:
        header = json.loads(str(z["header"]))
    header["format"] = "defop-operator-1"
    old = _rewrite(tmp_path / "op.npz", tmp_path / "old.npz", header)
    assert np.array_equal(DefOp.load(old)(Q), op(Q))
    header["meta"]["rank"] = 4
    q = op.handle_basis.size
    old = _rewrite(
        tmp_path / "op.npz",
        tmp_path / "old_c.npz",
        header,
        factor_A=np.ones((q, 4)),
        factor_B=np.ones((4, op.W.shape[1])),
    )
    back = DefOp.load(old)
    assert back.rank == 4 and back.factors[0].shape == (q - 1, 4)
    D = back(Q)
    assert np.abs(D[:, back.handles[back.moving]] - Q).max() <= 1e-12


@pytest.mark.parametrize("compressed", [False, True])
def test_fast_paths_switch_to_the_checked_path_beyond_the_overflow_guard(op_and_data, compressed):
    # evaluate_fast / evaluate_batch take their fast products only where |Q − P|² < R2 (every float32 product
    # provably finite); just inside and just outside the guard (|Q − P| ~ 1e7 here, where float32 cancellation in
    # the TPS sum leaves no accurate digits on the free vertices) the result is finite and the guarantees hold
    op = op_and_data[1]
    if compressed:
        op.compress(tol=1e-3)
    try:
        R = np.sqrt(op.fast_state().R2)
        assert 0 < R < np.inf
        rng = np.random.default_rng(5)
        u = rng.standard_normal(op.P.shape)
        u /= np.linalg.norm(u)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ExtrapolationWarning)
            for Q in (op.P + 0.999 * R * u, op.P + 1.001 * R * u):
                ref = op(Q)
                batch = op.evaluate_batch(np.stack([op.P, Q]))
                assert np.array_equal(batch[0], op.mesh.V)  # (8b) on the row at rest
                for D in (op.evaluate_fast(Q), batch[1]):
                    assert np.all(np.isfinite(D))
                    assert np.array_equal(D[op.handles[op.moving]], ref[op.handles[op.moving]])  # Prop. 2
    finally:
        op.decompress()


@pytest.mark.parametrize("chunk", [1, 7, 64])
def test_batch_chunks_give_the_single_frames(op_and_data, monkeypatch, chunk):
    # evaluate_batch works in chunks of rows when the fast matrices are small: any chunk size, with a short last
    # chunk and the rest pose among the rows, gives the single frames (same float32 matrices) and the guarantees
    s, op, Q, _ = op_and_data
    monkeypatch.setattr(DefOp, "BATCH_CHUNK", chunk)
    rng = np.random.default_rng(chunk)
    Qs = np.concatenate([Q, [op.P], op.P + 0.1 * rng.standard_normal((9, *op.P.shape))])[rng.permutation(len(Q) + 10)]
    for compressed in (False, True):
        if compressed:
            op.compress(tol=1e-3)
        try:
            out = np.full((len(Qs), op.n_vertices, 2), np.nan)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                batch = op.evaluate_batch(Qs, out=out)
                single = np.array([op.evaluate_fast(q) for q in Qs])
            assert batch is out and np.all(np.isfinite(out))
            assert np.abs(batch - single).max() <= 1e-6 * s.mesh.bbox_diagonal
            hv = op.handles[op.moving]
            assert np.abs(batch[:, hv] - Qs).max() <= 1e-12 * s.mesh.bbox_diagonal  # Prop. 2
            rest = np.flatnonzero(np.all(Qs == op.P, axis=(1, 2)))
            assert len(rest) and np.array_equal(batch[rest[0]], op.mesh.V)  # (8b)
        finally:
            op.decompress()


def test_timing_row_reports_sizes_rank_dtype_and_the_guarantees(op_and_data):
    # Table 1's row (defop.analysis.metrics.timing_row): the paper's conventions (|Φ| of the hat basis = #tris,
    # moving beside
    # fixed handles), FPS of both paths with the rank and dtype, and Prop. 2 / (8b) measured on the timed paths
    from types import SimpleNamespace

    s, op, Q, X = op_and_data
    try:
        row = dop.analysis.timing_row(s, op, SimpleNamespace(samples=Q, X=X), Q[:5], "hat", tol=1e-3)
        assert op.rank == row["rank"] >= 1 and row["dtype"] == row["dtype_exact"] == "float32"
        assert row["phi_paper"] == s.mesh.n_faces and row["phi"] == s.mesh.n_vertices
        assert (row["moving"], row["fixed"]) == (s.n_moving, len(s.handles) - s.n_moving)
        assert row["psi"] == hb.basis_size("tps", s.n_moving, len(Q) + 1)
        assert row["handles_err"] <= 1e-12 and row["rest_err"] == 0.0
        assert min(row["fps"], row["fps_median"], row["fps_exact"], row["ls_ms"]) > 0
    finally:
        op.decompress()

"""The compiled single frame (defop.operator.kernels): the same (★) as the checked numpy path, the guarantees exact."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_operator import op_and_data  # noqa: F401 - the shared fixture (250-vertex bar, TPS, 25 ARAP samples)

import defop as dop
from defop.operator import handle_bases as hb
from defop.operator import kernels
from defop.operator.defop import ExtrapolationWarning, checked_frames


@settings(max_examples=25, deadline=None)
@given(
    d=st.sampled_from([2, 3]),
    n=st.integers(1, 4),
    m=st.integers(1, 30),
    seed=st.integers(0, 2**31 - 1),
    far=st.sampled_from([0.0, 1e-8, 0.1, 1.0, 50.0]),
)
def test_kernel_psi_is_delta_raw_and_exactly_zero_at_rest(d, n, m, seed, far):
    rng = np.random.default_rng(seed)
    P = rng.standard_normal((n, d))
    basis = hb.TPSBasis(P, P + rng.standard_normal((m, n, d)), scale=float(rng.uniform(0.1, 3.0)))
    cm, czeps, inv_s2, log_kernel = basis.raw_constants()
    ell0 = kernels.tps_rest(cm, czeps, inv_s2, log_kernel)
    dz = far * rng.standard_normal(n * d)
    y = np.empty(basis.size - 1)
    kernels.tps_raw(dz, dz @ dz, cm, czeps, inv_s2, ell0, log_kernel, y)
    ref = basis.delta_raw(dz, dz @ dz, np.empty(basis.size - 1))  # the numpy path (its own ℓ(0))
    ell = basis.delta_raw(dz, dz @ dz, np.empty(basis.size - 1))[n * d :] + basis._ell0
    assert np.allclose(y, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ell).max()))
    if far == 0.0:
        assert not y.any()  # δψ(P) = 0 bit for bit: (8b) on the kernel path


@pytest.mark.parametrize("rank, dtype", [(None, np.float32), (3, np.float32), (None, np.float64), ("exact", None)])
def test_kernel_frame_is_the_checked_path_and_exact_at_handles_and_rest(op_and_data, rank, dtype):  # noqa: F811 - the fixture imported above
    s, op, Q, _ = op_and_data
    rng = np.random.default_rng(3)
    Qs = s.P_moving + 0.05 * s.mesh.bbox_diagonal * rng.standard_normal((20, *s.P_moving.shape))
    if rank != "exact":
        op.compress(rank=rank, tol=1e-3, dtype=dtype)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ExtrapolationWarning)
            ref = checked_frames(op, Qs, fast=True)  # numpy: δψ from delta_z, BLAS products
            for q, r in zip(Qs, ref):
                for path in (op, op.evaluate_fast):
                    X = path(q)
                    assert X.dtype == np.float64 and np.isfinite(X).all()
                    assert np.abs(X - r).max() <= 1e-5 * s.mesh.bbox_diagonal  # float32 round-off
                    assert np.array_equal(X[op.handles[op.moving]], q)  # Prop. 2, exactly
                    assert np.array_equal(X[op.handles[~op.moving]], s.mesh.V[op.handles[~op.moving]])
        for path in (op, op.evaluate_fast):
            assert np.array_equal(path(op.P.copy()), s.mesh.V)  # (8b), bit for bit
    finally:
        op.decompress()


def test_compressed_single_frame_still_warns_and_validates(op_and_data):  # noqa: F811 - the fixture imported above
    s, op, Q, _ = op_and_data
    op.compress(tol=1e-3)
    try:
        with pytest.warns(ExtrapolationWarning, match="moving handle 0 .* extrapolates") as rec:
            op(s.P_moving + [[3.0, 0.0]])
        assert rec[0].filename == __file__  # the warning points at the caller
        with warnings.catch_warnings():
            warnings.simplefilter("error", ExtrapolationWarning)
            op(Q[3])  # a training sample: within reach, no warning
            np.testing.assert_allclose(op(Q[3].tolist()), op(Q[3]), rtol=0, atol=1e-5 * s.mesh.bbox_diagonal)
        for bad in (np.full_like(s.P_moving, np.nan), s.P_moving[None, :, :1], s.P_moving + 1j):
            with pytest.raises(ValueError, match="Q"):
                op(bad)
        with pytest.raises(ValueError, match="not finite"):
            op(s.P_moving + 1e200)
    finally:
        op.decompress()


def test_polynomial_bases_take_the_kernel_products(op_and_data):  # noqa: F811 - the fixture imported above
    s, _, Q, X = op_and_data
    op = dop.operator.fit.fit_shape(s, Q, X, "quadratic", meta={"energy": "arap"}).compress(rank=4)
    ref = checked_frames(op, Q[:4], fast=True)
    for q, r in zip(Q[:4], ref):
        assert np.abs(op(q) - r).max() <= 1e-5 * s.mesh.bbox_diagonal
    assert np.array_equal(op(op.P.copy()), s.mesh.V)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), rows=st.integers(1, 20), cols=st.integers(1, 70))
def test_axpy8_is_a_matrix_vector_product(seed, rows, cols):
    rng = np.random.default_rng(seed)
    M, t = rng.standard_normal((rows, cols)), rng.standard_normal(rows)
    u = rng.standard_normal(cols)
    expect = u + t @ M
    kernels.axpy8(u, t, M)
    np.testing.assert_allclose(u, expect, rtol=1e-12, atol=1e-12 * np.abs(M).sum())

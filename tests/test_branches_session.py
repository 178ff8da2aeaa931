"""A follow session changes nothing on a rejected call: random sequences of valid and invalid calls.

Hypothesis draws sequences of session calls (``step``, ``__call__``, ``run``, ``set``, ``reset``) with valid
handle positions (near the samples, or far: an ExtrapolationWarning) and invalid ones (NaN, ±inf, a wrong shape,
strings, or so far that Ψ(Q) overflows). Every invalid call raises ValueError; the session's state (branch, frame,
jumps) after the whole sequence equals the state of a fresh session that made only the valid calls, and so do the
labels it returned. The bar of Fig. 10 with the fixtures of tests/test_branches.py.
"""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_branches import discovered

BAD_Q = {
    "nan": lambda P: np.full_like(P, np.nan),
    "inf": lambda P: P + np.inf,
    "-inf": lambda P: P - np.inf,
    "overflow": lambda P: P + 1e200,  # finite Q, Ψ(Q) (r² log r) not finite
    "shape": lambda P: np.zeros(P.size + 1),
    "batch": lambda P: np.stack([P, P]),  # a batch where one configuration is expected
    "string": lambda P: np.full(P.shape, "a"),
}


def state(s):
    return s.branch, s.frame, list(s.jumps)


def valid_q(P, xy, far):
    Q = P.copy()
    Q[0] += np.asarray(xy) * (10.0 if far else 1.0)
    return Q


valid = st.tuples(
    st.sampled_from(["step", "call", "run"]),
    st.tuples(st.floats(-0.35, 0.35), st.floats(-0.35, 0.35)),
    st.sampled_from([False, False, False, True]),  # far: outside the samples (warns, still valid)
)
invalid_q = st.tuples(st.sampled_from(["step", "call", "run"]), st.sampled_from(sorted(BAD_Q)))
labels = st.tuples(st.just("set"), st.sampled_from([0, 1, 2, -1, 1.0, True, "0", None]))
resets = st.tuples(st.just("reset"), st.sampled_from([None, 0, 1, 5]))


def apply(s, P, op):
    """Apply one drawn call; returns (valid, result). An invalid call must raise ValueError."""
    kind = op[0]
    if kind in ("set", "reset"):
        arg = op[1]
        ok = arg is None if kind == "reset" else False
        ok = ok or (isinstance(arg, int) and not isinstance(arg, bool) and arg in (0, 1))
        if ok:
            return True, getattr(s, kind)(arg)
        with pytest.raises(ValueError, match="branch must be one of the branch labels"):
            getattr(s, kind)(arg)
        return False, None
    if len(op) == 3:
        Q = valid_q(P, op[1], op[2])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if kind == "step":
                return True, s.step(Q)
            if kind == "call":
                X = s(Q)
                return True, (s.branch, X)
            return True, s.run(np.stack([Q, Q]))[0].tolist()
    Q = BAD_Q[op[1]](P)
    with pytest.raises(ValueError, match="Q"):
        if kind == "step":
            s.step(Q)
        elif kind == "call":
            s(Q)
        else:
            s.run(np.stack([P, Q]) if Q.shape == P.shape else np.stack([Q, Q]))
    return False, None


@settings(max_examples=40, deadline=None)
@given(
    start=st.sampled_from([None, 0, 1]),
    calls=st.lists(st.one_of(valid, invalid_q, labels, resets), min_size=1, max_size=12),
)
def test_rejected_calls_change_nothing(start, calls):
    shape, _, _, _, bop = discovered("bar")
    P = shape.P_moving
    s, ref = bop.session(start), bop.session(start)
    for op in calls:
        before = state(s)
        ok, out = apply(s, P, op)
        if not ok:
            assert state(s) == before, op  # a rejected call changes nothing
            continue
        _, expect = apply(ref, P, op)
        if op[0] == "call":
            assert out[0] == expect[0] and np.array_equal(out[1], expect[1])
        else:
            assert out == expect if op[0] != "run" else np.array_equal(out, expect)
        assert state(s) == state(ref)
    assert state(s) == state(ref)


def test_overflowing_q_names_q_and_no_argmax_over_nan():
    shape, _, _, _, bop = discovered("bar")
    s = bop.session(1)
    with pytest.raises(ValueError, match=r"is not finite at Q"):
        s.step(shape.P_moving + 1e200)
    with pytest.raises(ValueError, match=r"is not finite at Q"):
        bop.estimates(shape.P_moving + 1e200)
    assert state(s) == (1, 0, [])

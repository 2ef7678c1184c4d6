"""Fearnhead-Clifford optimal resampling: counts, threshold, unbiasedness, edge cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner import reference_resampling as plain
from roger_daemon.learner.resampling import fearnhead_resample, fearnhead_threshold

log_weight = st.one_of(st.floats(-50.0, 50.0), st.just(-np.inf))


def _lse(v: np.ndarray) -> float:
    m = np.max(v)
    return float(m + np.log(np.sum(np.exp(v - m))))


@given(lw=st.lists(log_weight, min_size=1, max_size=60), p=st.integers(1, 15),
       seed=st.integers(0, 2**16))
@settings(max_examples=300, deadline=None)
def test_resampling_properties(lw: list[float], p: int, seed: int) -> None:
    arr = np.array(lw)
    finite = np.isfinite(arr)
    if not finite.any():
        with pytest.raises(ValueError):
            fearnhead_resample(arr, p, np.random.default_rng(seed))
        return
    idx, out = fearnhead_resample(arr, p, np.random.default_rng(seed))
    # exactly min(P, #finite) distinct survivors, in increasing order, all with finite weight
    assert idx.size == min(p, int(finite.sum()))
    assert np.all(np.diff(idx) > 0)
    assert np.all(finite[idx])
    assert np.all(np.isfinite(out))
    assert _lse(out) == pytest.approx(0.0, abs=1e-12)
    w = np.exp(arr[finite] - _lse(arr[finite]))
    full_w = np.zeros(arr.size)
    full_w[finite] = w
    if finite.sum() <= p:  # M <= P keeps them all, weights unchanged
        np.testing.assert_allclose(np.exp(out), full_w[idx], rtol=1e-9, atol=1e-300)
        return
    inv_c, n_top = fearnhead_threshold(w, p)
    # the threshold solves sum_i min(c w_i, 1) = P
    assert np.sum(np.minimum(w / inv_c, 1.0)) == pytest.approx(p, rel=1e-9)
    # every putative with w >= 1/c survives and keeps its weight
    big = np.flatnonzero(full_w > inv_c * (1 + 1e-9))
    assert set(big.tolist()) <= set(idx.tolist())
    pos = np.searchsorted(idx, big)
    np.testing.assert_allclose(np.exp(out[pos]), full_w[big], rtol=1e-9)
    # the resampled ones all carry weight 1/c
    small = np.setdiff1d(idx, np.flatnonzero(full_w >= inv_c))
    np.testing.assert_allclose(np.exp(out[np.searchsorted(idx, small)]), inv_c, rtol=1e-9)


@given(lw=st.lists(st.floats(-40.0, 5.0), min_size=2, max_size=60), p=st.integers(1, 15),
       seed=st.integers(0, 2**16), ties=st.booleans())
@settings(max_examples=400, deadline=None)
def test_the_compiled_resampler_gives_the_plain_codes_bits(lw: list[float], p: int, seed: int,
                                                          ties: bool) -> None:
    """Same survivors, same log weights to the last bit, same draws as the plain Python and
    numpy resampler of the reference learner, with the C library's exp and log
    (:mod:`roger_daemon.learner.reference_resampling`); ties (rounded weights) included."""
    arr = np.round(np.array(lw), 0) if ties else np.array(lw)
    if arr.size <= p:
        return
    rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
    idx, out = fearnhead_resample(arr, p, rng_a)
    ref_idx, ref_out = plain.fearnhead_resample(arr, p, rng_b)
    assert idx.tolist() == ref_idx.tolist()
    assert out.tobytes() == ref_out.tobytes()
    assert rng_a.bit_generator.state == rng_b.bit_generator.state
    w, _ = plain.normalised_weights(arr)
    assert fearnhead_threshold(w, p) == plain.fearnhead_threshold(w, p)


@given(lw=st.lists(st.one_of(st.floats(-3000.0, 5.0), st.just(-np.inf)), min_size=1,
                   max_size=40),
       p=st.integers(1, 12), seed=st.integers(0, 2**16))
@settings(max_examples=300, deadline=None)
def test_the_plain_resampler_matches_on_every_path(lw: list[float], p: int, seed: int) -> None:
    """Dropped ``-inf`` putatives, ``M <= P``, and weights that underflow ``exp`` (the
    recursive path of docs/learner-math.md §5 step 5): the same bits and draws as well."""
    arr = np.array(lw)
    rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
    if not np.isfinite(arr).any():
        for resample, rng in ((fearnhead_resample, rng_a), (plain.fearnhead_resample, rng_b)):
            with pytest.raises(ValueError, match="no putative has a finite log weight"):
                resample(arr, p, rng)
        return
    idx, out = fearnhead_resample(arr, p, rng_a)
    ref_idx, ref_out = plain.fearnhead_resample(arr, p, rng_b)
    assert idx.tolist() == ref_idx.tolist()
    assert out.tobytes() == ref_out.tobytes()
    assert rng_a.bit_generator.state == rng_b.bit_generator.state


@given(lw=st.lists(st.floats(-40.0, 5.0), min_size=1, max_size=60), p=st.integers(1, 15))
@settings(max_examples=200, deadline=None)
def test_threshold_taus_are_the_numpy_formulas_bits(lw: list[float], p: int) -> None:
    """The one computation of ``R_L / (P - L)`` (read by the threshold and by the decision
    margin) gives the numpy formula's floats to the last bit, for as many ``L`` as there are
    weights and survivors."""
    from roger_daemon.learner.engine import jit

    w = np.exp(np.array(lw) - max(lw))
    ws = np.ascontiguousarray(np.sort(w / w.sum())[::-1])
    n = min(p, ws.size)
    expected = np.cumsum(ws[::-1])[::-1][:n] / np.arange(p, p - n, -1)
    assert jit.threshold_taus(ws, p).tobytes() == expected.tobytes()


def test_the_threshold_refuses_fewer_weights_than_survivors() -> None:
    """The compiled loop does not check bounds: too few weights is an error, not a read past
    the array; exactly ``n_keep`` weights keep them all (threshold below every weight)."""
    with pytest.raises(ValueError, match="at least n_keep = 3 weights, got 2"):
        fearnhead_threshold(np.array([0.5, 0.5]), 3)
    inv_c, n_top = fearnhead_threshold(np.array([0.5, 0.3, 0.2]), 3)
    assert n_top == 2 and inv_c == pytest.approx(0.2)


def test_resampling_is_unbiased() -> None:
    """E[new weight_i] = w_i, with weight 0 when not selected (a test that can fail)."""
    rng = np.random.default_rng(12345)
    w = rng.dirichlet(np.full(30, 0.3))
    lw = np.log(w)
    p, reps = 10, 20000
    total = np.zeros(30)
    total_sq = np.zeros(30)
    survived = np.zeros(30)
    for _ in range(reps):
        idx, out = fearnhead_resample(lw, p, rng)
        contrib = np.zeros(30)
        contrib[idx] = np.exp(out)
        total += contrib
        total_sq += contrib**2
        survived[idx] += 1
    mean = total / reps
    inv_c, n_top = fearnhead_threshold(w, p)
    assert 0 < n_top < p  # both regimes are exercised
    sure = w >= inv_c  # always kept with weight w_i: no randomness
    np.testing.assert_allclose(mean[sure], w[sure], rtol=1e-9)
    prob = np.minimum(w / inv_c, 1.0)
    often = ~sure & (prob * reps >= 20)  # normal approximation valid
    assert often.sum() >= 10
    se = np.sqrt((total_sq[often] / reps - mean[often] ** 2) / reps)
    z = (mean[often] - w[often]) / se
    assert np.max(np.abs(z)) < 4.5
    # survival probability is min(1, c w_i)
    z_p = (survived[often] / reps - prob[often]) / np.sqrt(prob * (1 - prob) / reps)[often]
    assert np.max(np.abs(z_p)) < 4.5
    rare = ~sure & ~often  # expected < 20 survivals: the count is Poisson-small
    assert np.all(survived[rare] <= prob[rare] * reps + 5 * np.sqrt(prob[rare] * reps) + 5)


def test_ties_keep_exactly_p_distinct() -> None:
    counts = np.zeros(20)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        idx, out = fearnhead_resample(np.zeros(20), 10, rng)
        assert idx.size == 10 and np.unique(idx).size == 10
        np.testing.assert_allclose(out, np.log(0.1))
        counts[idx] += 1
    assert np.all(np.abs(counts / 2000 - 0.5) < 0.05)


def test_underflow_and_invalid_weights() -> None:
    lw = np.array([0.0, -800.0, -1200.0, np.nan, -np.inf, -5.0, -1e6, -3.0, -2.0, -1.0, -0.5])
    idx, out = fearnhead_resample(lw, 6, np.random.default_rng(0))
    assert idx.size == 6 and 3 not in idx and 4 not in idx
    assert np.all(np.isfinite(out)) and _lse(out) == pytest.approx(0.0)
    # fewer finite putatives than P: keep them all, tiny ones included, no underflow to -inf
    idx, out = fearnhead_resample(np.array([0.0, -2000.0, -np.inf]), 5, np.random.default_rng(0))
    assert idx.tolist() == [0, 1]
    assert out[1] == pytest.approx(-2000.0)
    with pytest.raises(ValueError, match=r"\+inf"):
        fearnhead_resample(np.array([0.0, np.inf]), 1, np.random.default_rng(0))


def test_fewer_than_p_weights_survive_exp() -> None:
    """Weights 1000 nats below the best underflow to 0: the rest are resampled in log space
    (it used to fail with log(0)); the result equals resampling them on their own."""
    lw = np.array([0.0, -0.5, -1000.0, -1001.0, -1000.5, -1002.0, -1003.0])
    idx, out = fearnhead_resample(lw, 4, np.random.default_rng(3))
    assert idx.size == 4 and np.unique(idx).size == 4 and {0, 1} <= set(idx.tolist())
    assert _lse(out) == pytest.approx(0.0) and np.all(np.isfinite(out))
    top = np.log(np.exp(lw[:2]).sum())
    np.testing.assert_allclose(out[:2], lw[:2] - top, rtol=1e-12)
    ref_idx, ref_out = fearnhead_resample(lw[2:], 2, np.random.default_rng(3))
    assert (idx[2:] - 2).tolist() == ref_idx.tolist()
    rest = np.log(np.exp(lw[2:] + 1000.0).sum()) - 1000.0
    np.testing.assert_allclose(out[2:], ref_out + rest - top, rtol=1e-12)


def test_no_draw_when_nothing_to_resample() -> None:
    rng = np.random.default_rng(7)
    state = rng.bit_generator.state
    fearnhead_resample(np.array([0.0, -1.0]), 2, rng)
    assert rng.bit_generator.state == state


@given(lw=st.lists(st.floats(-30.0, 0.0), min_size=3, max_size=40), p=st.integers(2, 12),
       seed=st.integers(0, 2**16))
@settings(max_examples=200, deadline=None)
def test_a_perturbation_inside_the_decision_margin_changes_no_choice(
    lw: list[float], p: int, seed: int
) -> None:
    """The reported margin is a real safety distance: shaking every weight by a relative
    amount well inside it (as another BLAS kernel's round-off would) keeps the same putatives."""
    arr = np.array(lw)
    diag: dict[str, float] = {}
    idx, _ = fearnhead_resample(arr, p, np.random.default_rng(seed), diag)
    margin = diag["margin"]
    assert margin >= 0.0
    if not np.isfinite(margin) or margin < 1e-9:
        return  # every putative kept, or a genuine near-tie
    shake = np.random.default_rng(seed + 1).uniform(-1.0, 1.0, arr.size) * margin / 20.0
    idx2, _ = fearnhead_resample(arr + np.log1p(shake), p, np.random.default_rng(seed))
    assert idx2.tolist() == idx.tolist()


def test_the_margin_is_zero_at_an_exact_tie_and_infinite_without_a_decision() -> None:
    diag: dict[str, float] = {}
    fearnhead_resample(np.log([0.5, 0.3, 0.2]), 3, np.random.default_rng(0), diag)
    assert diag["margin"] == np.inf  # M <= P: every putative kept, nothing decided
    # two places for [1/2, 1/4, 1/4]: the keep-outright test w_1 <= R_0 / P = 1/2 sits exactly
    # on its boundary
    fearnhead_resample(np.log([0.5, 0.25, 0.25]), 2, np.random.default_rng(0), diag)
    assert diag["margin"] == pytest.approx(0.0, abs=1e-12)

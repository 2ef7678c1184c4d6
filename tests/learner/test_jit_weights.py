"""The putatives' compiled log weights (roger_daemon/learner/engine/jit_weights.py), the gates' CRP
terms and the resampler's log-sum-exp, bit for bit against plain Python (the C library's
``math.log``, ``math.exp``, sums in index order); and the learned state the same whichever
SIMD loops numpy picks (docs/reproducibility.md, *numpy's SIMD loops*)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner.engine import jit

finite = st.floats(-30.0, 30.0, allow_nan=False)
positive = st.floats(1e-6, 50.0)


def _density(sq: float, var: float, dims: int) -> float:
    return -0.5 * dims * (math.log(2.0 * math.pi) + math.log(var)) - 0.5 * sq / var


@given(sq=st.floats(0.0, 1e4), var=positive, dims=st.integers(1, 12))
@settings(max_examples=300, deadline=None)
def test_the_gaussian_density_is_the_formula_with_libm_log(sq: float, var: float,
                                                           dims: int) -> None:
    got = jit.gaussian_log_density(sq, var, dims)
    assert got == _density(sq, var, dims)  # the same floats, not within a tolerance
    # the density itself: log N(y; 0, var I) by scipy for a y with |y|^2 = sq
    from scipy.stats import multivariate_normal

    y = np.zeros(dims)
    y[0] = math.sqrt(sq)
    ref = multivariate_normal(np.zeros(dims), var * np.eye(dims)).logpdf(y)
    assert got == pytest.approx(ref, rel=1e-10, abs=1e-10)


@given(data=st.data(), m=st.integers(1, 8), d_y=st.integers(1, 10), dims=st.integers(1, 10))
@settings(max_examples=200, deadline=None)
def test_slot_log_likelihoods_sum_in_index_order(data: st.DataObject, m: int, d_y: int,
                                                 dims: int) -> None:
    cap = m + 3
    slots = np.array(data.draw(st.permutations(range(cap)))[:m], dtype=np.int64)
    y = np.array(data.draw(st.lists(finite, min_size=d_y, max_size=d_y)))
    means = np.array(data.draw(st.lists(finite, min_size=m * d_y, max_size=m * d_y)))
    means = means.reshape(m, d_y)
    latent = np.array(data.draw(st.lists(positive, min_size=m, max_size=m)))
    noise = data.draw(positive)
    out = np.full(cap, -np.inf)
    jit.slot_log_likelihoods(slots, y, means, latent, noise, dims, out)
    want = np.full(cap, -np.inf)
    for j, s in enumerate(slots.tolist()):
        sq = 0.0
        for a in range(d_y):
            sq += (y[a] - means[j, a]) * (y[a] - means[j, a])
        want[s] = _density(sq, noise + latent[j], dims)
    assert out.tobytes() == want.tobytes()


def test_putative_log_weights_add_each_putatives_gp_factor() -> None:
    base = np.array([-1.0, -2.0, -3.0, -4.0, 0.5])
    flat_slots = np.array([2, -1, 0, 2, -1], dtype=np.int64)
    slot_ll = np.array([-0.25, -np.inf, -7.0])
    got = jit.putative_log_weights(base, flat_slots, slot_ll, -10.0)
    assert got.tolist() == [-8.0, -12.0, -3.25, -11.0, -9.5]


def test_the_crp_terms_are_the_gates_density_plus_libm_log_of_the_count() -> None:
    from roger_daemon.learner.engine.gates import GatePool

    rng = np.random.default_rng(4)
    pool = GatePool(3, 0.0, 0.1, 1.0, 6.0)
    for s in range(4):
        pool.set_prior_updated(s, rng.normal(size=3))
        pool.update_many(np.array([s], dtype=np.int64), rng.normal(size=3))
    slots = np.array([3, 0, 2], dtype=np.int64)
    npts = np.array([5, 1, 7, 123456789], dtype=np.int64)
    x = rng.normal(size=3)
    out = np.full(pool.capacity, 99.0)
    pool.crp_log_terms(slots, x, npts, out)
    dens = pool.log_predictive(slots, x)
    for j, s in enumerate(slots.tolist()):
        assert out[s] == dens[j] + math.log(int(npts[s]))
    assert out[1] == 99.0  # a slot not asked for is left alone


@given(lw=st.lists(finite, min_size=1, max_size=80))
@settings(max_examples=300, deadline=None)
def test_log_sum_exp_is_libm_in_index_order(lw: list[float]) -> None:
    top = max(lw)
    total = 0.0
    for v in lw:
        total += math.exp(v - top)
    assert jit.log_sum_exp(np.array(lw)) == top + math.log(total)


# learn the shipped AIBO prefix (1,500 pairs: numpy's AVX-512 loops moved this state, while the
# synthetic stream's did not) and print the learned state's digest
_LEARN = """
import json
from roger_daemon.bench.learner import load_stream
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.learner import Roger
from roger_daemon.learner.synthetic import BENCH_SEED
s = load_stream("aibo", 1500, BENCH_SEED, [])
m = Roger(s.x.shape[1], s.y.shape[1], s.params, seed=3)
for i in range(s.x.shape[0]):
    m.learn_one(s.x[i], s.y[i])
print(json.dumps(array_digest(m.state_dict())))
"""


def _avx512_loops() -> bool:
    from numpy._core._multiarray_umath import __cpu_features__

    return bool(__cpu_features__.get("AVX512F") and __cpu_features__.get("AVX512_SKX"))


@pytest.mark.skipif(not _avx512_loops(), reason="numpy has no AVX-512 loops on this CPU: "
                    "both runs would take the same ones")
def test_the_learned_state_does_not_depend_on_numpys_simd_loops() -> None:
    """The same state digest with numpy's AVX-512 loops (this CPU's) and with them disabled
    (``NPY_DISABLE_CPU_FEATURES``, the loops an AVX2 host runs): every ``exp`` and ``log`` of
    the learning path is the C library's."""
    digests = []
    for disabled in ("", "X86_V4 AVX512_ICL AVX512_SPR"):
        env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": disabled}
        run = subprocess.run([sys.executable, "-c", _LEARN], env=env, capture_output=True,
                             text=True, timeout=600, check=True)
        digests.append(json.loads(run.stdout.strip().splitlines()[-1]))
    assert digests[0] == digests[1]

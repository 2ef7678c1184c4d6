"""Several experts per compiled call, over the cores (roger_daemon/learner/engine/jit_batch.py).

The batched kernels run each expert's own kernels, one expert per iteration of a parallel
loop, so the floats must not depend on the number of threads: these tests compare one thread
(each expert's kernels called from Python) with two (batched) bit for bit, and the batched
evaluation with each expert's own ``terms``.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner.engine import jit, jit_threads
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.sogp_batch import evaluate_many, update_evaluated, update_many

from .batched import learn_stream

pytestmark = pytest.mark.usefixtures("batch_every_size")  # small experts, batched (conftest)


def _expert(n_points: int, seed: int, *, capacity: int = 12, prior_mean: bool = False
            ) -> SparseOnlineGP:
    rng = np.random.default_rng(seed)
    gp = SparseOnlineGP(3, 2, RBFKernel(0.5, 3), 0.1, capacity, 1e-6, prior_mean=prior_mean)
    for _ in range(n_points):
        gp.update(rng.uniform(-1, 1, 3), rng.normal(size=2))
    return gp


def _same_state(a: SparseOnlineGP, b: SparseOnlineGP) -> None:
    assert (a.n, a.n_points, a.q_refreshes) == (b.n, b.n_points, b.q_refreshes)
    for u, v in ((a._B, b._B), (a._A, b._A), (a._Cp, b._Cp), (a._Qp, b._Qp)):
        np.testing.assert_array_equal(u, v)
    assert a.novelty_margin == b.novelty_margin


@pytest.mark.parametrize("threads", [1, 2])
def test_batched_evaluation_is_each_experts_own(threads: int) -> None:
    """``evaluate_many`` on one thread (:func:`.jit_evaluate.evaluate_experts`) and on two
    (:func:`.jit_batch.terms_batch`), 40 experts (more than one call of ``EVALUATION_WIDTH``;
    sizes from one basis vector to full at 12, with and without a prior mean) == ``gp.terms``,
    bit for bit: the means, the latent variances and every expert's full terms; with an empty
    expert among them, each is evaluated on its own, the same floats."""
    jit.set_threads(threads)
    live = [_expert(n, seed, prior_mean=seed % 3 == 0)
            for seed, n in enumerate([1, 5, 12, 40, 60] * 8)]
    x = np.array([0.1, -0.3, 0.7])
    for experts in (live, [*live[:3], _expert(0, 7), *live[3:]]):
        got = evaluate_many(experts, x)
        assert len(experts) > jit.EVALUATION_WIDTH
        for j, gp in enumerate(experts):
            k0, ck0, mean0, latent0 = gp.terms(x)
            k, ck, mean, latent = got.terms(j)
            for u, v in ((k, k0), (ck, ck0), (mean, mean0), (got.means[j], mean0)):
                np.testing.assert_array_equal(u, v)
            assert latent == latent0 == got.latent[j]


@pytest.mark.parametrize(("experts", "calls"), [(1, 1), (20, 1), (32, 1), (33, 2), (65, 3)])
def test_the_evaluation_takes_up_to_evaluation_width_experts_per_call(
        monkeypatch: pytest.MonkeyPatch, experts: int, calls: int) -> None:
    """One batched call (one parallel region) per ``EVALUATION_WIDTH`` experts: a step's ~20
    distinct experts at the paper's parameters make one, not 16 + 4 (docs/performance.md, *One
    parallel region for the evaluation*)."""
    jit.set_threads(2)
    made: list[int] = []
    kernel = jit.terms_batch

    def counted(*args: object) -> None:
        made.append(int(args[1]))  # count: the experts this call evaluates
        kernel(*args)

    monkeypatch.setattr(jit, "terms_batch", counted)
    gps = [_expert(5 + seed % 7, seed) for seed in range(experts)]
    got = evaluate_many(gps, np.array([0.2, -0.1, 0.4]))
    assert len(made) == calls and sum(made) == experts
    assert max(made) <= jit.EVALUATION_WIDTH == 32
    for j in (0, experts - 1):
        np.testing.assert_array_equal(got.means[j], gps[j].terms(np.array([0.2, -0.1, 0.4]))[2])


def test_learning_does_not_depend_on_the_thread_count() -> None:
    """The same stream on one thread and on two: the same state, bit for bit (the experts
    fill, so the batched fused step runs)."""
    one, two = learn_stream(1), learn_stream(2)
    assert max(g.n for g in two.distinct_experts()) == 20
    a, b = one.state_dict(), two.state_dict()
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize("threads", [1, 2])
def test_update_many_takes_every_outcome_like_one_expert_at_a_time(threads: int) -> None:
    """Full experts whose point is novel (fused step), not novel (a basis vector's own input:
    projection update) or whose ``Q`` drifted (re-inverted first): ``update_many`` leaves each
    as its own ``update`` does, up to round-off, and counts the re-inversion."""
    jit.set_threads(threads)
    experts = [_expert(60, seed) for seed in range(4)]
    experts[2] = experts[1].copy()
    assert all(gp.fusable() for gp in experts)
    x = experts[1].B[3].copy()  # a basis vector of experts 1 and 2: gamma = 0, not novel
    drifted = experts[2]
    drifted._Qp *= 1.5  # k^T Q k = 1.5: gamma < -tol k*
    drifted._forget_diagonals()
    y = np.array([0.2, -0.4])
    twins = [gp.copy() for gp in experts]
    update_many(experts, x, y, [gp.terms(x) for gp in experts])
    for gp, twin in zip(experts, twins, strict=True):
        twin.update(x, y)
        assert (gp.n, gp.n_points, gp.q_refreshes) == (twin.n, twin.n_points, twin.q_refreshes)
        np.testing.assert_array_equal(gp.B, twin.B)
        for u, v in ((gp.A, twin.A), (gp.C, twin.C), (gp.Q, twin.Q)):
            np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-12)
    assert drifted.q_refreshes == 1
    assert experts[1].novelty_margin == pytest.approx(1e-6)  # gamma 0: |0 - 1e-6 k*| / k*


def test_update_many_is_the_same_on_one_and_two_threads() -> None:
    """Every outcome at once, learned on one thread and on two: bit for bit."""
    states = []
    for threads in (1, 2):
        jit.set_threads(threads)
        experts = [_expert(60, seed) for seed in range(jit.WIDTH + 3)]  # two batches
        rng = np.random.default_rng(9)
        for _ in range(5):
            x, y = rng.uniform(-1, 1, 3), rng.normal(size=2)
            update_many(experts, x, y, [gp.terms(x) for gp in experts])
        experts[1] = experts[0].copy()
        experts[1]._Qp *= 1.5  # drifted at a basis vector of expert 0, which keeps it
        experts[1]._forget_diagonals()
        x = experts[0].B[0].copy()
        update_many(experts, x, y, [gp.terms(x) for gp in experts])
        assert experts[1].q_refreshes == 1
        states.append(experts)
    for a, b in zip(*states, strict=True):
        _same_state(a, b)


@settings(max_examples=300, deadline=None)
@given(kqk=st.floats(-3.0, 3.0), kstar=st.sampled_from([0.5, 1.0, 2.0]),
       threshold=st.sampled_from([0.0, 1e-6, 1e-3, 0.5]))
def test_novelty_test_is_the_documented_rule(kqk: float, kstar: float, threshold: float) -> None:
    """Oracle: docs/learner-math.md §2.5 step 3 written out."""
    raw = kstar - kqk
    gamma = 0.0 if raw < 1e-12 else raw
    want = (gamma, raw < -1e-6 * kstar, not (gamma < threshold * kstar or gamma <= 0.0))
    assert jit.novelty_test(kqk, kstar, threshold, 1e-12, 1e-6) == want


@settings(max_examples=200, deadline=None)
@given(gamma=st.floats(0.0, 3.0), kstar=st.sampled_from([0.5, 1.0, 2.0]),
       threshold=st.sampled_from([0.0, 1e-6, 1e-3, 0.5]),
       q_max=st.floats(1e-3, 1e12), floor=st.sampled_from([-1.0, 0.0, 1e-9, 1e-3]))
def test_the_margin_and_the_clean_up_are_the_documented_rules(
        gamma: float, kstar: float, threshold: float, q_max: float, floor: float) -> None:
    """Oracles: the novelty margin |gamma - threshold k*| / k* (docs/reproducibility.md) and
    step 6's test 1 / Q_ii >= floor, off for floor <= 0 (docs/learner-math.md §2.7)."""
    assert jit.novelty_margin(gamma, kstar, threshold) == abs(gamma - threshold * kstar) / kstar
    assert jit.keeps_basis_vectors(q_max, floor) is (floor <= 0.0 or 1.0 / q_max >= floor)


def test_the_clean_up_test_takes_a_zero_diagonal_without_raising() -> None:
    assert jit.keeps_basis_vectors(0.0, 1e-9)  # 1 / 0 = inf, as numpy makes it


def test_experts_are_batched_on_several_threads_with_enough_work(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import numba

    monkeypatch.setattr(jit_threads, "BATCH_MIN_ENTRIES", 100)
    jit.set_threads(2)
    several = numba.config.NUMBA_NUM_THREADS >= 2
    assert jit.batch_worth(100) is several
    assert not jit.batch_worth(99)
    jit.set_threads(1)
    assert not jit.batch_worth(10**9)


def test_only_empty_experts_are_evaluated_one_at_a_time() -> None:
    jit.set_threads(2)
    experts = [_expert(0, 1), _expert(0, 2)]
    assert evaluate_many(experts, np.zeros(3)).latent.tolist() == [1.0, 1.0]  # k* each


def test_the_default_is_one_thread_on_numbas_workqueue_layer(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """numba's ``workqueue`` layer (no OpenMP, no TBB) wakes its threads slower than the
    kernels run: after ``warm_up`` finds it, the default (``set_threads(None)``) is one
    thread; an explicit count is kept."""
    import numba

    monkeypatch.setattr(numba, "threading_layer", lambda: "workqueue")
    monkeypatch.setattr(jit_threads, "_workqueue", False)
    jit.set_threads(None)
    jit.check_threading_layer()
    assert jit.threads() == 1
    jit.set_threads(2)
    jit.check_threading_layer()
    assert jit.threads() == min(2, numba.config.NUMBA_NUM_THREADS)


def test_the_layer_check_waits_for_numbas_first_parallel_call(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Before any parallel kernel has run numba cannot name its layer (ValueError): the
    default is then left as it is."""
    import numba

    def not_yet() -> str:
        raise ValueError("Threading layer is not initialized.")

    monkeypatch.setattr(numba, "threading_layer", not_yet)
    jit.set_threads(None)
    before = jit.threads()
    jit.check_threading_layer()
    assert jit.threads() == before


def test_set_threads_rejects_a_count_below_one() -> None:
    with pytest.raises(ValueError, match="threads must be an integer >= 1 or None, got 0"):
        jit.set_threads(0)


def test_set_threads_caps_at_numbas_thread_count() -> None:
    import numba

    jit.set_threads(10_000)
    assert jit.threads() == numba.config.NUMBA_NUM_THREADS
    jit.set_threads(None)
    assert 1 <= jit.threads() <= numba.config.NUMBA_NUM_THREADS


@pytest.mark.parametrize("threads", [1, 2])
def test_copy_many_fills_every_pending_copy(threads: int) -> None:
    """Copies deferred by ``BufferPool.copy_of(..., pending)`` (a kept buffer and new ones,
    more than one batch of ``WIDTH``) are filled by ``copy_many``, on one thread or two."""
    from roger_daemon.learner.engine.buffers import BufferPool, PendingCopy, copy_many

    jit.set_threads(threads)
    rng = np.random.default_rng(2)
    sources = [rng.normal(size=45) for _ in range(jit.WIDTH + 2)]
    pool = BufferPool(limit=1)
    kept = np.full(45, 7.0)
    pool.give(kept)
    pending: list[PendingCopy] = []
    copies = [pool.copy_of(src, pending) for src in sources]
    assert copies[0] is kept and len(pending) == len(sources)
    assert np.all(kept == 7.0)  # not filled yet
    copy_many(pending)
    for src, dst in zip(sources, copies, strict=True):
        np.testing.assert_array_equal(dst, src)
        assert dst is not src


def _outcome_set(prior_mean: bool) -> tuple[list[SparseOnlineGP], np.ndarray]:
    """Full experts whose point is novel, not novel (a basis vector's own input) or whose
    ``Q`` drifted, plus one not full (learns on its own), and the point."""
    experts = [_expert(60, seed, prior_mean=prior_mean) for seed in range(5)]
    experts[2] = experts[1].copy()
    experts[2]._Qp *= 1.5  # drifted: k^T Q k = 1.5 at experts[1]'s basis vector
    experts[2]._forget_diagonals()
    experts.append(_expert(4, 9, prior_mean=prior_mean))
    return experts, experts[1].B[3].copy()


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("prior_mean", [False, True])
def test_update_evaluated_is_update_many_bit_for_bit(threads: int, prior_mean: bool) -> None:
    """The step's update, which reads the experts' terms off their evaluation, leaves every
    expert as :func:`update_many` with each expert's own terms does, bit for bit: every
    outcome, with and without a prior mean, an expert not evaluated, and the experts of two
    evaluations (the pruned step evaluates in two stages)."""
    jit.set_threads(threads)
    y = np.array([0.2, -0.4])
    for how in ("one evaluation", "one expert not evaluated", "two evaluations"):
        mine, x = _outcome_set(prior_mean)
        theirs = [gp.copy() for gp in mine]
        got = evaluate_many(mine, x)
        refs: list[tuple[object, int] | None] = [(got, j) for j in range(len(mine))]
        if how == "one expert not evaluated":
            refs[4] = None  # its terms are computed when needed
        elif how == "two evaluations":
            rest = evaluate_many(mine[3:], x)
            refs[3:] = [(rest, j) for j in range(len(mine) - 3)]
        update_evaluated(mine, x, y, refs)  # type: ignore[arg-type]
        update_many(theirs, x, y, [gp.terms(x) for gp in theirs])
        assert mine[2].q_refreshes == 1
        for a, b in zip(mine, theirs, strict=True):
            _same_state(a, b)
            np.testing.assert_array_equal(a.mean_offset, b.mean_offset)

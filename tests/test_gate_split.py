"""Split gates (roger_daemon/gate_split.py): exact marginals, splits from the inputs alone."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.gate_split import SPLIT_LAMBDA0, SplitGates, niw_log_marginal, split_points
from roger_daemon.learner import RogerParams
from roger_daemon.learner.engine.gates import GatePool
from roger_daemon.learner.partition import fit_partition
from simulator.experiment.goal_plan import configure, plan_from_args
from simulator.experiment.pipeline import gated
from simulator.experiment.training import Demonstrations


@settings(max_examples=20, deadline=None)
@given(n=st.integers(1, 40), d=st.integers(1, 4), seed=st.integers(0, 10_000),
       lambda0=st.sampled_from([0.01, 0.1, 1.0]))
def test_the_marginal_is_the_chain_of_the_gate_predictives(n: int, d: int, seed: int,
                                                           lambda0: float) -> None:
    """``log p(X)`` in closed form equals the sum of the gate's sequential Student-t
    predictives ``log t(x_i | x_<i)`` (the chain rule; the gate's own recursion)."""
    x = np.random.default_rng(seed).normal(size=(n, d))
    gate = GatePool(d, 0.0, 0.1, lambda0, d + 1.0, capacity=1)
    gate.set_prior(0)
    chain = 0.0
    for row in x:
        chain += float(gate.log_predictive(np.zeros(1, dtype=np.int64), row)[0])
        gate.update(0, row)
    assert niw_log_marginal(x, 0.0, 0.1, lambda0, d + 1.0) == pytest.approx(chain, rel=1e-9,
                                                                          abs=1e-9)


def _blobs(seed: int, gap: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.normal(scale=0.05, size=(60, 3))
    b = rng.normal(scale=0.05, size=(40, 3)) + np.array([gap, 0.0, 0.0])
    order = rng.permutation(100)
    return np.vstack([a, b])[order], np.array([0] * 60 + [1] * 40)[order]


def test_two_separate_clusters_become_two_parts_and_one_stays_one() -> None:
    prior = (0.0, 0.1, 0.1, 4.0)
    x, truth = _blobs(0, gap=1.0)
    parts = split_points(x, prior, math.log(0.5), max_parts=4, min_points=5, seed=0)
    assert len(set(parts.tolist())) == 2
    assert all(len(set(parts[truth == k].tolist())) == 1 for k in (0, 1))
    one = split_points(x[truth == 0], prior, math.log(0.5), max_parts=4, min_points=5, seed=0)
    assert set(one.tolist()) == {0}


def test_max_parts_one_never_splits_and_min_points_is_kept() -> None:
    x, _ = _blobs(1, gap=1.0)
    prior = (0.0, 0.1, 0.1, 4.0)
    assert set(split_points(x, prior, 0.0, max_parts=1, min_points=5, seed=0).tolist()) == {0}
    # the smaller cluster (40 points) cannot be a part of at least 41
    assert set(split_points(x, prior, 0.0, max_parts=4, min_points=41, seed=0).tolist()) == {0}


def _model(x: np.ndarray, groups: list[int]) -> object:
    y = np.array([[1.0] if g == 0 else [-1.0] for g in groups])
    params = RogerParams(lambda0=0.1, nu0=4.0)
    return fit_partition(x, y, groups, params=params, seed=0)


def test_without_a_split_the_parts_are_the_experts_gates() -> None:
    """``max_parts = 1``: one part per expert, whose gate probabilities are the model's own
    ``p(k | x)`` (paper Algorithm 2)."""
    x, truth = _blobs(2, gap=1.0)
    model = _model(x, truth.tolist())
    split = SplitGates(model, x, max_parts=1)
    assert [q.expert for q in split.parts] == [0, 1]
    for probe in x[:10] + 0.01:
        mine = split.part_probs(probe)
        theirs = {e.expert_id: e.gate_prob for e in model.predict_multimap(probe)}  # type: ignore[attr-defined]
        assert mine == pytest.approx([theirs[0], theirs[1]], rel=1e-9, abs=1e-12)


def test_parts_below_the_models_min_support_do_not_compete_as_its_experts_do() -> None:
    """With ``min_support = 20`` a 5-point expert has gate probability 0 in the model
    (paper Algorithm 2 with the support rule); its part has 0 too, the others are the model's
    probabilities, and no split makes a part smaller than the support."""
    x, truth = _blobs(6, gap=1.0)
    tiny = np.random.default_rng(7).normal(scale=0.05, size=(5, 3)) + np.array([0.0, 1.0, 0.0])
    x = np.vstack([x, tiny])
    groups = truth.tolist() + [2] * 5
    y = np.array([[float(g)] for g in groups])
    model = fit_partition(x, y, groups, params=RogerParams(lambda0=0.1, nu0=4.0, min_support=20),
                          seed=0)
    split = SplitGates(model, x, max_parts=1)
    for probe in (x[0], tiny[0], tiny.mean(axis=0)):
        theirs = {e.expert_id: e.gate_prob for e in model.predict_multimap(probe)}
        assert theirs[2] == 0.0
        assert split.part_probs(probe) == pytest.approx([theirs[0], theirs[1], theirs[2]],
                                                        rel=1e-9, abs=1e-12)
    assert min(q.n for q in SplitGates(model, x).parts if q.expert != 2) >= 20


def test_an_expert_spanning_two_clusters_is_split_and_keeps_its_gp() -> None:
    """One expert holding both blobs: two parts, both of expert 0, each gate owning its
    blob; the labels of the points are not an argument (the split uses the inputs only)."""
    x, truth = _blobs(3, gap=1.0)
    model = _model(x, [0] * len(x))
    split = SplitGates(model, x, max_parts=4, min_points=5)
    assert [q.expert for q in split.parts] == [0, 0]
    assert sorted(q.n for q in split.parts) == [40, 60]
    for k in (0, 1):
        probe = x[truth == k][0]
        owner = split.point_part[np.flatnonzero(truth == k)[0]]
        assert int(np.argmax(split.part_probs(probe))) == owner


def test_the_default_prior_scatter_splits_a_model_with_the_papers_gate_prior() -> None:
    """The split test's own prior scatter (``SPLIT_LAMBDA0``), not the model's: a model with
    the default gate prior (``lambda0 = 1``) still has its spanning expert split, which the
    model's own scatter would not do on inputs this tight."""
    x, _ = _blobs(5, gap=0.5)
    y = np.ones((len(x), 1))
    model = fit_partition(x, y, [0] * len(x), params=RogerParams(), seed=0)
    assert model.terms.params.lambda0 == 1.0
    assert SPLIT_LAMBDA0 < 1.0
    assert len(SplitGates(model, x, min_points=5).parts) == 2
    assert len(SplitGates(model, x, min_points=5, lambda0=1.0).parts) == 1


def test_the_zenoh_path_serves_split_gates_from_its_checkpoints(tmp_path: Path) -> None:
    """``--gates split`` on the Zenoh path: models/roger-K is the split gates' one-particle
    ROGER model (what the in-process row acts with, float for float), its points named by
    the stream's labels; its evaluation jobs' daemons run one particle; merged groups as
    before."""
    from roger_daemon.daemon.checkpoint import array_digest, list_checkpoints, read_checkpoint
    from roger_daemon.gate_split_model import split_model
    from simulator.experiment.goal_scoring import _eval_jobs
    from simulator.experiment.zenoh_run import ZenohRun

    parser = argparse.ArgumentParser()
    configure(parser)
    plan = plan_from_args(parser.parse_args(["--out", str(tmp_path), "--gates", "split",
                                             "--controllers", "hcc,roger"]))
    assert plan.gates == "split" and not plan.in_process and plan.to_json()["gates"] == "split"
    x, truth = _blobs(8, gap=1.0)
    model = _model(x, [0] * len(x))
    stream = Demonstrations(x, np.zeros((len(x), 1)), ["a" if t else "b" for t in truth],
                            np.zeros(len(x), dtype=np.int64), np.arange(len(x)), 0)
    run = ZenohRun(plan, RogerParams(), None, {}, {})
    unimap: Any = _model(x, [0] * len(x))
    digests = run._checkpoints(stream, [(0, model)], unimap, [])
    want = split_model(SplitGates(model, x, seed=0))
    assert want.n_experts == 2
    ck = read_checkpoint(list_checkpoints(tmp_path / "models" / "roger-0", "aibo")[0])
    assert ck.meta.model_digest == array_digest(want.state_dict()) == digests["roger:0"]
    jobs = [j for j in _eval_jobs(plan, tmp_path / "models", RogerParams(), digests)
            if j.name == "roger:0"]
    assert jobs and all(j.learner["particles"] == 1 for j in jobs)


def test_split_gates_reach_the_roger_and_autonomous_rows() -> None:
    """``gated``: the models themselves with ``niw``, their split views with ``split``; the
    transitioner's controller acts with the same object."""
    x, truth = _blobs(4, gap=1.0)
    model = _model(x, [0] * len(x))
    stream = Demonstrations(x, np.zeros((len(x), 1)), ["a"] * len(x),
                            np.zeros(len(x), dtype=np.int64), np.arange(len(x)), 0)
    niw: Any = SimpleNamespace(gates="niw", controllers=("roger",))
    split: Any = SimpleNamespace(gates="split", controllers=("roger",))
    assert gated(niw, stream, [(0, model)])[0][1] is model
    ((seed, view),) = gated(split, stream, [(0, model)])
    assert seed == 0 and isinstance(view, SplitGates) and len(view.parts) == 2
    probe = x[0]
    _, table = view.predict_table(probe)
    own = model.predict_one(probe)
    assert table.expert_ids == [0, 1] and sum(table.gate_probs) == pytest.approx(1.0)
    for row in range(2):  # both parts answer with expert 0's GP
        assert np.array_equal(table.means[row], own.mean)

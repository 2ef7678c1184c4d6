"""The plain reference learner (``roger_daemon.learner.reference``) against the fast one.

For every lever of ``RogerParams``, one short stream: learned by :class:`Roger` and by
:class:`ReferenceRoger` with the same params and seed, the two make the same discrete decisions
(every point's expert in the MAP particle, the experts' ids, sizes and basis sizes, the number
of particles and the MAP particle, each probe's chosen expert and multimap) and agree on every
float to the replay tolerance (``REL_TOL``, normwise relative: predictions, gate probabilities,
particle log weights).  Each case also shows that its lever did something on its stream (an
event the reference counts, or a behaviour that differs from the lever off), so no agreement
is vacuous.  Then the reference's own parts against closed forms, and its imports.
"""

from __future__ import annotations

import ast
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.stats import multivariate_t

from roger_daemon.config import parse_config
from roger_daemon.learner import PRESETS, Roger, RogerParams
from roger_daemon.learner.reference import ReferenceRoger
from roger_daemon.learner.reference_expert import ReferenceGate, ReferenceGP
from roger_daemon.learner.synthetic import sqrt_multimap, subtask_stream
from roger_daemon.replay.compare import (
    REL_TOL,
    behaviour,
    behaviour_differences,
    probe_inputs,
    rel_err,
)

Stream = tuple[np.ndarray, np.ndarray]
AIBO = Path(__file__).parents[2] / "roger_daemon" / "bench" / "data" / "aibo-demonstrations.npz"

#: small dims, a kernel and novelty threshold that keep K_B well conditioned (with the paper's
#: 1e-6 and a broad kernel, round-off decides the floats, docs/reproducibility.md)
# nu0 = 24 (the paper's, for 23-D inputs): the streams below were chosen so that each lever acts
# with it; the d_x + 1 default would make some of them inert on these 4-D streams
BASE = RogerParams(particles=5, beta=15, theta_w=0.7, novelty_threshold=1e-3, nu0=24.0)


@cache
def subtasks() -> Stream:
    """120 pairs of the synthetic subtask stream at 4 -> 2 dims (a multimap)."""
    st = subtask_stream(120, d_x=4, d_y=2, seed=3)
    return st.x, st.y


@cache
def ramp() -> Stream:
    """1-D sweeps 0, 0.5, ..., 9.5: the later basis vectors leave the middle ones within
    1e-3 x threshold of their span (the geometric clean-up, docs/learner-math.md §2.5 step 6)."""
    t = np.arange(120)
    x = (0.5 * (t % 20))[:, None]
    return x, np.sin(x) + 0.01 * np.cos(7.0 * t)[:, None]


@cache
def far_outputs() -> Stream:
    """The two-branch toy with outputs of size ~200 and no scaling: a wrong expert's weight
    underflows ``exp`` (the resampler's §5 step 5 path)."""
    st = sqrt_multimap(120, seed=2)
    return st.x, 200.0 * st.y


@cache
def aibo(n: int) -> Stream:
    """The first ``n`` recorded AIBO demonstration pairs (23 -> 9, raw units)."""
    with np.load(AIBO) as data:
        return data["x"][:n].copy(), data["y"][:n].copy()


def aibo_params() -> RogerParams:
    """The daemon's default: the ``default`` preset and the AIBO profile."""
    params: RogerParams = parse_config({}).robots[0].params
    return params


@cache
def two_branches() -> Stream:
    """``y = +sqrt(x)`` and ``-sqrt(x)`` interleaved: the gates overlap everywhere."""
    st = sqrt_multimap(120, seed=0)
    return st.x, st.y


@dataclass(frozen=True)
class Case:
    """A stream for the ``levers`` (``RogerParams`` fields) at their values in ``params``.

    The lever must have done something there: the ``events`` the reference counts occurred,
    and the model differs from the one with the levers at their defaults (the rest of
    ``params`` unchanged)."""

    params: RogerParams
    levers: tuple[str, ...] = ()
    stream: Callable[[], Stream] = subtasks
    events: tuple[str, ...] = ()


DEFAULT_LEVERS = tuple(PRESETS["default"])
CASES = {
    "paper rules (BV additions, projections, Q re-inversions)":
        Case(BASE, events=("additions", "projections", "re-inversions", "draws")),
    "kernel_dim_scaling": Case(BASE.replace(kernel_dim_scaling="grollman", theta_w=0.4),
                               ("kernel_dim_scaling",)),
    "likelihood_normaliser": Case(BASE.replace(likelihood_normaliser="grollman"),
                                  ("likelihood_normaliser",)),
    "novelty_threshold": Case(BASE.replace(novelty_threshold=0.3), ("novelty_threshold",)),
    "beta (capacity, KL deletion)": Case(BASE.replace(beta=4), ("beta",),
                                         events=("capacity deletions",)),
    "geometric clean-up": Case(BASE.replace(particles=4, beta=30, theta_w=1.0, theta_n=0.01,
                                            novelty_threshold=7e-3), stream=ramp,
                               events=("clean-up deletions",)),
    "expert_choice": Case(BASE.replace(expert_choice="sample"), ("expert_choice",),
                          two_branches),
    "predict_empty_expert": Case(BASE.replace(predict_empty_expert=True),
                                 ("predict_empty_expert",)),
    "prune_log_margin": Case(BASE.replace(prune_log_margin=3.0), ("prune_log_margin",),
                             events=("pruned experts",)),
    "x and y offset and scale": Case(BASE.replace(
        x_offset=(0.1, -0.2, 0.3, 0.0), x_scale=(0.5, 2.0, 1.0, 0.7), y_offset=(1.0, -1.0),
        y_scale=(2.0, 0.5)), ("x_offset", "x_scale", "y_offset", "y_scale")),
    "gp_prior_mean": Case(BASE.replace(gp_prior_mean="expert"), ("gp_prior_mean",)),
    "sticky_kappa": Case(BASE.replace(sticky_kappa=3.0), ("sticky_kappa",)),
    "sticky_kappa inf": Case(BASE.replace(sticky_kappa=math.inf), ("sticky_kappa",)),
    "min_support": Case(BASE.replace(theta_w=0.3, min_support=30), ("min_support",),
                        two_branches),
    "input_weights": Case(BASE.replace(input_weights=(1.0, 0.0, 2.5, 0.5)), ("input_weights",)),
    "one particle": Case(BASE.replace(particles=1), ("particles",)),
    "many particles": Case(BASE.replace(particles=16), ("particles",)),
    "priors and noise": Case(BASE.replace(alpha=2.0, mu0=0.2, kappa0=0.5, lambda0=0.3, nu0=6.0,
                                          theta_n=0.02),
                             ("alpha", "mu0", "kappa0", "lambda0", "nu0", "theta_n")),
    "underflowing weights": Case(BASE.replace(theta_w=0.3, theta_n=1e-4), stream=far_outputs,
                                 events=("underflows",)),
    "default preset": Case(RogerParams.preset("default", particles=5, beta=15),
                           DEFAULT_LEVERS),
}


def learn_both(params: RogerParams, x: np.ndarray, y: np.ndarray, seed: int = 1, *,
               generator: bool = False) -> tuple[Roger, ReferenceRoger]:
    """The fast learner and the reference, each fed the stream (seeded by ``seed``, or by a
    numpy Generator of it each)."""

    def make() -> Any:
        return np.random.default_rng(seed) if generator else seed

    fast = Roger(x.shape[1], y.shape[1], params, seed=make())
    ref = ReferenceRoger(x.shape[1], y.shape[1], params, seed=make())
    for xi, yi in zip(x, y, strict=True):
        fast.learn_one(xi, yi)
        ref.learn_one(xi, yi)
    return fast, ref


def assert_agree(fast: Roger, ref: ReferenceRoger, x: np.ndarray) -> dict[str, Any]:
    """The same discrete decisions, floats within ``REL_TOL``; the reference's behaviour."""
    probes = probe_inputs(x)
    got = behaviour(ref, probes)
    assert behaviour_differences(behaviour(fast, probes), got) == []
    assert fast.basis_sizes() == ref.basis_sizes()
    assert fast.n_particles == ref.n_particles
    lw_fast, lw_ref = fast.particle_log_weights(), ref.particle_log_weights()
    assert int(np.argmax(lw_fast)) == int(np.argmax(lw_ref))
    assert rel_err(lw_fast, lw_ref) <= REL_TOL
    return got


def same_model(a: Roger, b: Roger, probes: list[list[float]]) -> bool:
    """Behaviour and particle weights equal (within the tolerance)."""
    wa, wb = a.particle_log_weights(), b.particle_log_weights()
    return (behaviour_differences(behaviour(a, probes), behaviour(b, probes)) == []
            and wa.shape == wb.shape and rel_err(wa, wb) <= REL_TOL)


@pytest.mark.parametrize("name", list(CASES))
def test_the_fast_learner_agrees_with_the_reference(name: str) -> None:
    case = CASES[name]
    x, y = case.stream()
    fast, ref = learn_both(case.params, x, y)
    assert_agree(fast, ref, x)
    for event in case.events:
        assert ref.stats[event] > 0, (event, dict(ref.stats))
    if case.levers:  # the lever changes the model on this stream
        defaults = RogerParams()
        off = Roger(x.shape[1], y.shape[1], case.params.replace(
            **{f: getattr(defaults, f) for f in case.levers}), seed=1)
        for xi, yi in zip(x, y, strict=True):
            off.learn_one(xi, yi)
        assert not same_model(fast, off, probe_inputs(x))


def test_a_generator_seed_spawns_the_same_streams() -> None:
    """A numpy Generator as the seed: both spawn the same two child streams from it."""
    x, y = subtasks()
    fast, ref = learn_both(BASE.replace(expert_choice="sample"), x[:60], y[:60], seed=7,
                           generator=True)
    assert_agree(fast, ref, x[:60])


def test_the_aibo_stream_with_the_daemons_default() -> None:
    """23 -> 9, the ``default`` preset and the AIBO profile (scaling, zero input weights), as a
    daemon with no config runs it: the first 250 recorded pairs."""
    x, y = aibo(250)
    fast, ref = learn_both(aibo_params(), x, y, seed=0)
    assert_agree(fast, ref, x)
    assert ref.n_experts > 1 and ref.stats["projections"] > 0


def test_the_paper_at_aibo_dimensions_on_a_budget() -> None:
    """The paper's parameters on the 23 -> 9 synthetic stream with a small ``beta``: full
    experts take the fast learner's fused add-then-delete step."""
    st = subtask_stream(100)
    fast, ref = learn_both(RogerParams(beta=25), st.x, st.y, seed=0)
    assert_agree(fast, ref, st.x)
    assert ref.stats["capacity deletions"] > 0


@pytest.mark.slow
def test_the_whole_aibo_stream_with_the_daemons_default() -> None:
    x, y = aibo(1500)
    fast, ref = learn_both(aibo_params(), x, y, seed=0)
    assert_agree(fast, ref, x)


@pytest.mark.slow
def test_the_benchmark_stream_with_the_papers_parameters() -> None:
    """``roger bench learner``'s stream and parameters (beta = 300), 400 points."""
    st = subtask_stream(400)
    fast, ref = learn_both(RogerParams(), st.x, st.y, seed=0)
    assert_agree(fast, ref, st.x)


# -- the reference's parts against closed forms -------------------------------------------


def test_the_gate_is_the_student_t_of_the_niw_posterior() -> None:
    """§3.1 batch posterior and §3.3 predictive, by scipy, against the rank-1 recursion."""
    rng = np.random.default_rng(0)
    d, n = 3, 7
    xs = rng.normal(size=(n, d))
    params = RogerParams(mu0=0.3, kappa0=0.5, lambda0=2.0, nu0=4.0)
    gate = ReferenceGate.prior(params, d)
    for x in xs:
        gate = gate.updated(x)
    xbar = xs.mean(axis=0)
    scatter = (xs - xbar).T @ (xs - xbar)
    kappa, nu = 0.5 + n, 4.0 + n
    mu0 = np.full(d, 0.3)
    lam = 2.0 * np.eye(d) + scatter + (0.5 * n / kappa) * np.outer(xbar - mu0, xbar - mu0)
    df = nu - d + 1
    t = multivariate_t(loc=(0.5 * mu0 + n * xbar) / kappa, shape=lam * (kappa + 1) / (kappa * df),
                       df=df)
    for q in rng.normal(size=(5, d)):
        assert gate.log_predictive(q) == pytest.approx(float(t.logpdf(q)), rel=1e-12)


def test_the_gp_without_budget_or_threshold_is_the_exact_gp() -> None:
    """§2.8: every point a basis vector, A = (K + s0^2 I)^-1 Y, C = -(K + s0^2 I)^-1,
    Q = K^-1; with the prior mean (§8), the exact GP on y - m."""
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, (12, 2))
    y = 1.5 + np.sin(3 * x) + 0.1 * rng.normal(size=(12, 2))
    for prior_mean in ("zero", "expert"):
        params = RogerParams(theta_w=0.5, theta_n=0.05, novelty_threshold=0.0, beta=100,
                             gp_prior_mean=prior_mean)
        gp = ReferenceGP(params, 2, 2, Counter())
        for xi, yi in zip(x, y, strict=True):
            gp.learn(xi, yi)
        m = y.mean(axis=0) if prior_mean == "expert" else np.zeros(2)
        gram = np.exp(-np.sum((x[:, None] - x[None]) ** 2, axis=2) / (2 * 0.25))
        inv = np.linalg.inv(gram + 0.05 * np.eye(12))
        np.testing.assert_allclose(gp.m, m, atol=1e-13)
        np.testing.assert_allclose(gp.A[:, :2], inv @ (y - m), atol=1e-8)
        np.testing.assert_allclose(gp.C, -inv, atol=1e-8)
        np.testing.assert_allclose(gp.Q, np.linalg.inv(gram), rtol=1e-8, atol=1e-8)


def test_a_drifted_q_is_re_inverted_before_the_novelty_test() -> None:
    """Pitfall 6: ``Q_ii < 1/k*`` is impossible in exact arithmetic; the next point re-inverts
    ``Q`` from the basis first."""
    stats: Counter[str] = Counter()
    params = RogerParams(theta_w=0.5, novelty_threshold=1e-3, beta=50)
    gp = ReferenceGP(params, 1, 1, stats)
    for v in (0.0, 0.7, 1.4):
        gp.learn(np.array([v]), np.array([math.sin(v)]))
    gp.Q = gp.Q * 0.5  # drifted: every Q_ii below 1
    gp.learn(np.array([0.35]), np.array([0.3]))
    assert stats["drift re-inversions"] == 1
    gram = np.exp(-((gp.B - gp.B.T) ** 2) / (2 * 0.25))
    np.testing.assert_allclose(gp.Q, np.linalg.inv(gram), rtol=1e-9)


def test_the_same_arguments_are_refused_and_bad_pairs_change_nothing() -> None:
    """One owner of the constructor's checks (``model_args``); ``learn_one``'s ValueError
    leaves the model as it was; before learning both predict the prior."""
    for args in ((0, 1), (2, 1.5), (23, 9)):
        for cls in (Roger, ReferenceRoger):
            if args == (23, 9):
                cls(*args)
                continue
            with pytest.raises(ValueError):
                cls(*args)
    # an explicit nu0 must exceed d_x - 1 (the default, d_x + 1, always does)
    for cls in (Roger, ReferenceRoger):
        cls(26, 1)
        with pytest.raises(ValueError, match="nu0"):
            cls(26, 1, RogerParams(nu0=24.0))
    ref, fast = ReferenceRoger(2, 1, BASE, seed=0), Roger(2, 1, BASE, seed=0)
    p_ref, p_fast = ref.predict_one([0.1, 0.2]), fast.predict_one([0.1, 0.2])
    assert (p_ref.expert_id, p_ref.gate_prob) == (p_fast.expert_id, p_fast.gate_prob) == (-1, 1.0)
    np.testing.assert_array_equal(p_ref.var, p_fast.var)
    ref.learn_one([0.1, 0.2], [0.3])
    for bad in (([0.1], [0.3]), ([0.1, math.nan], [0.3]), ([0.1, 0.2], [0.3, 0.4])):
        with pytest.raises(ValueError):
            ref.learn_one(*bad)
    assert ref.n_learned == 1 and ref.assignments().tolist() == [0]


# -- imports --------------------------------------------------------------------------------

_PLAIN = {"reference", "reference_expert", "reference_resampling", "model_args", "params",
          "scaling", "prediction"}


def _learner_imports(module: str) -> set[str]:
    """What a learner module imports of the project (``roger_daemon.learner`` modules by their
    short names, anything else in full) and of numba."""
    path = Path(__file__).parents[2] / "roger_daemon" / "learner" / f"{module}.py"
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module == "roger_daemon.learner":
            names = [f"roger_daemon.learner.{a.name}" for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""]
        else:
            continue
        for name in names:
            if name.startswith("roger_daemon.learner."):
                out.add(name.removeprefix("roger_daemon.learner.").split(".")[0])
            elif name.split(".")[0] in ("numba", "roger_daemon"):
                out.add(name)
    return out


def test_the_reference_imports_nothing_of_the_compiled_layer() -> None:
    """Its modules, and every learner module they import, in turn: plain modules only."""
    seen, todo = set(), ["reference"]
    while todo:
        module = todo.pop()
        seen.add(module)
        if module in _PLAIN:  # anything else fails below, unread
            todo.extend(sorted(_learner_imports(module) - seen))
    assert seen == _PLAIN, seen ^ _PLAIN

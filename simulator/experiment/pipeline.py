"""Phases of ``roger experiment goal-scoring`` shared by the Zenoh and the in-process paths.

* :func:`train_models`: ROGER once per learner seed, and the unimap GP (DPA), on one stream;
* :func:`fit_segmentation_oracle`: one sparse online GP per *true* subtask (same learner
  parameters), the ceiling for learned experts;
* :func:`evaluate_in_process`: closed-loop episodes of any of the controllers in this process;
* :func:`run_in_process`: the whole experiment without Zenoh (``--in-process``).

The demonstrator's labels never enter ROGER's learning: they choose the points kept by the
downsampling (paper section IV), group the trained experts for the transitioner (section IV.A),
train the oracle, and score the segmentation.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.labels import majority_labels
from simulator.controllers.demo_noise import seeded
from simulator.controllers.hcc import HCC
from simulator.episodes import SoccerSim, StartLocation
from simulator.experiment import inprocess as ip
from simulator.experiment.averaging import MultimapNeighbourhood
from simulator.experiment.metrics import downsample_per_label
from simulator.experiment.training import Demonstrations, train

__all__ = [
    "controllers_for",
    "fit_transitions",
    "downsample",
    "downsample_indices",
    "evaluate_in_process",
    "MergedGroups",
    "merge_all",
    "merge_expert_groups",
    "fit_segmentation_oracle",
    "gated",
    "group_controllers",
    "make_hcc",
    "make_sim",
    "run_in_process",
    "save_training_data",
    "train_models",
]


Episodes = dict[str, list[dict[str, Any]]]


def make_sim(plan: Any) -> SoccerSim:
    """A simulator with the plan's task config, vision and time limit (as ``roger sim``)."""
    from simulator.config import load_config

    cfg = load_config(plan.task_config)
    cfg = replace(cfg, vision=plan.vision,
                  episode=replace(cfg.episode, time_limit=plan.time_limit))
    return SoccerSim(cfg)


def make_hcc(plan: Any) -> HCC:
    """The HCC with the plan's task config (as ``roger hcc --config``)."""
    from simulator.controllers.hcc_node import hcc_from_config

    return hcc_from_config(plan.task_config)


def demonstrate(plan: Any) -> tuple[Demonstrations, list[Any]]:
    """The plan's demonstrations (every tick) and their episode records: the HCC from
    ``plan.locations`` x ``plan.shots`` in a simulator of its own, closed afterwards; with
    ``plan.demo_noise`` its executed commands disturbed
    (:mod:`simulator.controllers.demo_noise`, its generator from the demonstration's seed)."""
    sim = make_sim(plan)
    noise = seeded(getattr(plan, "demo_noise", 0.0), plan.seeds["demo_sim"])
    try:
        return ip.demonstrate(sim, make_hcc(plan), plan.locations, plan.shots,
                              plan.seeds["demo_sim"], noise=noise)
    finally:
        sim.close()


def downsample(data: Demonstrations, plan: Any) -> Demonstrations:
    """At most ``plan.per_subtask`` random points per subtask, order kept (paper section IV)."""
    return data.subset(downsample_indices(data, plan))


def downsample_indices(data: Demonstrations, plan: Any) -> npt.NDArray[np.int64]:
    """The indices :func:`downsample` keeps (seeded with ``plan.seeds["downsample"]``)."""
    rng = np.random.default_rng(plan.seeds["downsample"])
    return downsample_per_label(data.labels, plan.per_subtask, rng)


def learner_seeds(plan: Any) -> list[int]:
    """The learner seeds of the plan's ROGER models."""
    return [plan.seeds["learner"] + k for k in range(plan.learner_seeds)]


def train_models(stream: Demonstrations, params: Any, plan: Any,
                 progress: Callable[[int], None] | None = None
                 ) -> tuple[list[tuple[int, Any]], Any, float]:
    """ROGER per learner seed and the unimap GP; returns ``(models, unimap, ROGER seconds)``."""
    from roger_daemon.learner import Roger, UnimapGP

    d_x, d_y = stream.x.shape[1], stream.y.shape[1]
    models = []
    train_s = 0.0
    for seed in learner_seeds(plan):
        model = Roger(d_x=d_x, d_y=d_y, params=params, seed=seed)
        train_s += train(model, stream.x, stream.y, progress=progress)
        models.append((seed, model))
    unimap = UnimapGP(d_x=d_x, d_y=d_y, params=params, seed=plan.seeds["learner"])
    train(unimap, stream.x, stream.y)
    return models, unimap, train_s


def fit_segmentation_oracle(stream: Demonstrations, params: Any, seed: int) -> dict[str, Any]:
    """One sparse online GP per true subtask, with ROGER's learner parameters."""
    from roger_daemon.learner import UnimapGP

    d_x, d_y = stream.x.shape[1], stream.y.shape[1]
    return ip.fit_oracle(stream, lambda _y: UnimapGP(d_x=d_x, d_y=d_y, params=params, seed=seed))


@dataclass(frozen=True)
class MergedGroups:
    """ROGER model K's experts merged per group (:func:`merge_expert_groups`)."""

    seed: int
    model: Any  # a one-particle Roger whose experts are the groups
    group_of_point: list[str]  # the group (majority label of its ROGER expert) of each point
    labels: dict[int, str]  # merged expert id -> group name


def gated(plan: Any, stream: Demonstrations, models: Sequence[tuple[int, Any]]
          ) -> list[tuple[int, Any]]:
    """The models the ``roger`` and ``autonomous`` rows act with: each ROGER model itself
    (``--gates niw``), or its experts with split gates (``--gates split``,
    :class:`roger_daemon.gate_split.SplitGates` over ``stream``, the points it learned; no
    label is read)."""
    if getattr(plan, "gates", "niw") == "niw":
        return list(models)
    from roger_daemon.gate_split import SplitGates

    return [(seed, SplitGates(model, stream.x, seed=seed)) for seed, model in models]


def fit_transitions(data: Demonstrations, models: Sequence[tuple[int, Any]],
                    plan: Any, stream: Demonstrations) -> list[Any]:
    """A learned FSM over each ROGER model's experts (the parts of their split gates with
    ``--gates split``, :func:`gated`; docs/autonomy.md), from every demonstration tick in
    order (``data``: the whole stream, before downsampling; an episode starts where its tick
    is 0; ``stream``: the points the models learned). Labels are not read. None unless the
    plan evaluates ``autonomous``."""
    if "autonomous" not in plan.controllers:
        return []
    from roger_daemon.fsm import aibo_memory, fit_fsm

    spec = aibo_memory()
    return [fit_fsm(model, data.x, data.y, data.tick == 0, spec, executed=data.executed)
            for _, model in gated(plan, stream, models)]


def merge_expert_groups(stream: Demonstrations, model: Any, params: Any,
                        seed: int) -> MergedGroups:
    """ROGER's experts merged per group: a one-particle ROGER model
    (:func:`roger_daemon.learner.partition.fit_partition`) whose expert for each majority label
    learns, in stream order, the points the MAP particle assigned to that label's experts
    (docs/goal-scoring.md, "merged groups").

    The paper groups experts by the subtask that generated most of their data (section IV.A)
    and lets the transitioner pick within a group; here each group's experts become one expert
    (same learner parameters, one particle). ROGER's partition picks the points; the labels
    only name each expert's group, as for the transitioner.
    """
    from roger_daemon.groups import merge_groups

    merged, group_of_point = merge_groups(stream.x, stream.y, stream.labels, model,
                                          params=params, seed=seed)
    labels = majority_labels(np.asarray(merged.assignments()).tolist(), group_of_point)
    return MergedGroups(seed, merged, group_of_point, labels)


def controllers_for(plan: Any, stream: Demonstrations, models: Sequence[tuple[int, Any]],
                    unimap: Any, oracle: Mapping[str, Any] | None,
                    merged: Sequence[MergedGroups] = (), fsms: Sequence[Any] = ()
                    ) -> dict[str, Any]:
    """Controller key -> in-process controller, for the plan's controllers."""
    out: dict[str, Any] = {}
    if "hcc" in plan.controllers:
        out["hcc"] = make_hcc(plan)
    if "oracle" in plan.controllers and oracle is not None:
        out["oracle"] = ip.OracleController(make_hcc(plan), oracle)
    models = gated(plan, stream, models)
    if "roger" in plan.controllers:
        for k, (_, model) in enumerate(models):
            groups = majority_labels(np.asarray(model.assignments()).tolist(), stream.labels)
            out[f"roger:{k}"] = ip.TransitionerController(make_hcc(plan), model, groups,
                                                          plan.rule)
    if "autonomous" in plan.controllers:
        for k, ((_, model), fsm) in enumerate(zip(models, fsms, strict=True)):
            out[f"autonomous:{k}"] = ip.AutonomousController(model, fsm)
    if "dpa" in plan.controllers:
        out["dpa"] = ip.MeanController(unimap, MultimapNeighbourhood(stream.x, stream.y))
    out.update(group_controllers(plan, merged))
    return out


def group_controllers(plan: Any, merged: Sequence[MergedGroups]) -> dict[str, Any]:
    """``groups:K`` -> ROGER model K's merged groups, chosen by the HCC's transitions (the same
    transitioner as ROGER's experts; each subtask has one expert)."""
    if "groups" not in plan.controllers:
        return {}
    return {f"groups:{k}": ip.TransitionerController(make_hcc(plan), m.model, m.labels,
                                                     plan.rule)
            for k, m in enumerate(merged)}


def merge_all(stream: Demonstrations, models: Sequence[tuple[int, Any]], params: Any,
              plan: Any) -> list[MergedGroups]:
    """Every ROGER model's merged groups (none unless the plan evaluates ``groups``)."""
    if "groups" not in plan.controllers:
        return []
    return [merge_expert_groups(stream, model, params, seed) for seed, model in models]


def evaluate_in_process(plan: Any, controllers: Mapping[str, Any],
                        locations: Sequence[int] | None = None,
                        starts: Sequence[StartLocation] | None = None,
                        on_episode: Callable[[str, ip.EpisodeRecord], None] | None = None
                        ) -> Episodes:
    """``plan.attempts`` episodes per location for each controller (evaluation seed)."""
    sim = make_sim(plan)
    locs = list(plan.locations if locations is None else locations)
    out: Episodes = {}
    try:
        for key, controller in controllers.items():
            def hook(rec: ip.EpisodeRecord, key: str = key) -> None:
                if on_episode is not None:
                    on_episode(key, rec)

            recs = ip.evaluate(sim, controller, locs, plan.attempts, plan.seeds["eval_sim"],
                               starts=starts, on_episode=hook)
            out[key] = [r.to_json() for r in recs]
    finally:
        sim.close()
    return out


def save_training_data(out: Any, stream: Demonstrations, model: Any) -> None:
    """``OUT/training-data.npz``: the downsampled stream both paths trained on (x, y, labels,
    location, tick) and the first learner seed's assignments; ``scripts/ablation.py`` reads
    it."""
    np.savez_compressed(
        out / "training-data.npz", x=stream.x, y=stream.y,
        labels=np.array(stream.labels, dtype=np.str_), location=stream.location,
        tick=stream.tick, assignments=np.asarray(model.assignments()),
    )


def run_in_process(plan: Any, params: Any, console: Any,
                   context: dict[str, Any] | None = None) -> dict[str, Any]:
    """The whole experiment in this process; returns ``results.json``'s content.

    ``context`` (if given) receives the stream, the models and the oracle (for
    ``--start-poses``)."""
    from simulator.experiment.report import build_results, write_figures

    timings: dict[str, float] = {}
    t_all = t0 = time.monotonic()
    data, records = demonstrate(plan)
    demos = [r.to_json() for r in records]
    timings["demonstrations"] = round(time.monotonic() - t0, 2)
    stream = downsample(data, plan)
    t0 = time.monotonic()
    models, unimap, train_s = train_models(stream, params, plan)
    oracle = fit_segmentation_oracle(stream, params, plan.seeds["learner"])
    merged = merge_all(stream, models, params, plan)
    timings["training"] = round(time.monotonic() - t0, 2)
    t0 = time.monotonic()
    fsms = fit_transitions(data, models, plan, stream)
    timings["transitions"] = round(time.monotonic() - t0, 2)
    save_training_data(plan.out, stream, models[0][1])
    if context is not None:
        context.update(stream=stream, models=models, unimap=unimap, oracle=oracle,
                       merged=merged, fsms=fsms)
    console.log(f"learned {len(stream)} pairs: "
                + ", ".join(f"seed {s}: {m.n_experts} experts" for s, m in models))
    t0 = time.monotonic()
    episodes = evaluate_in_process(
        plan, controllers_for(plan, stream, models, unimap, oracle, merged, fsms),
        on_episode=lambda k, r: console.log(f"{k:>8} location {r.location} "
                                            f"#{r.repetition}: {r.failure_mode}"))
    timings["evaluation"] = round(time.monotonic() - t0, 2)
    results = build_results(plan=plan, params=params, demos=demos, data=data, stream=stream,
                            models=models, episodes=episodes, check=None, train_s=train_s,
                            errors=[], fsms=fsms)
    results["figures"] = write_figures(plan.out, stream, np.asarray(models[0][1].assignments()),
                                       results)
    results["timings_s"] = {**timings, "total": round(time.monotonic() - t_all, 2)}
    return results

"""One demonstration stream's trained models in one file, for the multi-stream protocol.

:func:`prepare_stream` runs the in-process experiment's first phases for one stream
(demonstrations, downsampling, ROGER per learner seed, the unimap GP, the segmentation oracle,
the merged groups, the learned transitions: :mod:`simulator.experiment.pipeline`) and writes
everything the evaluation needs to ``OUT/prepared.npz``: named arrays only (each model's own
``state_dict``), no pickle. :func:`load_bundle` reads it back as a :class:`Bundle`, from
which :func:`simulator.experiment.pipeline.controllers_for` builds the controllers in any
process (docs/goal-scoring.md, "Several demonstration streams").
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.atomic import atomic_write
from simulator.experiment.training import Demonstrations

__all__ = ["Bundle", "load_bundle", "prepare_stream"]

FILE = "prepared.npz"


@dataclass
class Bundle:
    """A prepared stream: what :func:`simulator.experiment.pipeline.controllers_for` and
    :func:`simulator.experiment.report.build_results` take."""

    stream: Demonstrations
    models: list[tuple[int, Any]]
    unimap: Any
    oracle: dict[str, Any]
    merged: list[Any]
    fsms: list[Any]
    demos: list[dict[str, Any]]
    data_labels: list[str]
    train_s: float
    timings: dict[str, float] = field(default_factory=dict)
    data_tick: Any = None  # each demonstration pair's tick in its episode


def _put(out: dict[str, np.ndarray], prefix: str, state: dict[str, np.ndarray]) -> None:
    out.update({f"{prefix}/{k}": v for k, v in state.items()})


def _take(arrays: Any, prefix: str) -> dict[str, np.ndarray]:
    n = len(prefix) + 1
    return {k[n:]: np.asarray(arrays[k]) for k in arrays.files if k.startswith(prefix + "/")}


def prepare_stream(plan: Any, params: Any) -> dict[str, float]:
    """Demonstrate, train and fit one stream (``plan.seed``); write ``plan.out/prepared.npz``.
    Returns the phases' wall times."""
    from simulator.experiment import pipeline as pl

    timings: dict[str, float] = {}
    t0 = time.monotonic()
    data, records = pl.demonstrate(plan)
    timings["demonstrations"] = round(time.monotonic() - t0, 2)
    stream = pl.downsample(data, plan)
    t0 = time.monotonic()
    models, unimap, train_s = pl.train_models(stream, params, plan)
    oracle = pl.fit_segmentation_oracle(stream, params, plan.seeds["learner"])
    merged = pl.merge_all(stream, models, params, plan)
    timings["training"] = round(time.monotonic() - t0, 2)
    t0 = time.monotonic()
    fsms = pl.fit_transitions(data, models, plan, stream)
    timings["transitions"] = round(time.monotonic() - t0, 2)
    out: dict[str, np.ndarray] = {
        "stream/x": stream.x, "stream/y": stream.y, "stream/location": stream.location,
        "stream/tick": stream.tick, "stream/labels": np.array(stream.labels, dtype=np.str_),
        "data/labels": np.array(data.labels, dtype=np.str_), "data/tick": data.tick,
    }
    for k, (_, model) in enumerate(models):
        _put(out, f"roger{k}", model.state_dict())
    _put(out, "unimap", unimap.state_dict())
    for label, gp in oracle.items():
        _put(out, f"oracle:{label}", gp.state_dict())
    for k, m in enumerate(merged):
        _put(out, f"groups{k}", m.model.state_dict())
    for k, fsm in enumerate(fsms):
        _put(out, f"fsm{k}", fsm.state_dict())
    meta = {"learner_seeds": [s for s, _ in models], "oracle": sorted(oracle),
            "groups": [{"seed": m.seed, "labels": {str(e): v for e, v in m.labels.items()},
                        "group_of_point": m.group_of_point} for m in merged],
            "fsms": len(fsms), "demos": [r.to_json() for r in records],
            "unpaired": data.unpaired, "train_s": train_s, "timings": timings}
    out["meta"] = np.array(json.dumps(meta))
    plan.out.mkdir(parents=True, exist_ok=True)
    with atomic_write(plan.out / FILE) as f:
        np.savez(f, **out)  # type: ignore[arg-type]
    return timings


def load_bundle(directory: Path) -> Bundle:
    """The :class:`Bundle` :func:`prepare_stream` wrote in ``directory``."""
    from roger_daemon.fsm import LearnedFSM
    from roger_daemon.learner import load_model
    from simulator.experiment.pipeline import MergedGroups

    with np.load(directory / FILE, allow_pickle=False) as arrays:
        meta = json.loads(str(arrays["meta"]))
        stream = Demonstrations(arrays["stream/x"], arrays["stream/y"],
                                [str(s) for s in arrays["stream/labels"]],
                                arrays["stream/location"], arrays["stream/tick"], 0)
        models = [(seed, load_model(_take(arrays, f"roger{k}")))
                  for k, seed in enumerate(meta["learner_seeds"])]
        unimap = load_model(_take(arrays, "unimap"))
        oracle = {label: load_model(_take(arrays, f"oracle:{label}"))
                  for label in meta["oracle"]}
        merged = [MergedGroups(g["seed"], load_model(_take(arrays, f"groups{k}")),
                               list(g["group_of_point"]),
                               {int(e): v for e, v in g["labels"].items()})
                  for k, g in enumerate(meta["groups"])]
        fsms = [LearnedFSM.from_state_dict(_take(arrays, f"fsm{k}"))
                for k in range(int(meta["fsms"]))]
        data_labels = [str(s) for s in arrays["data/labels"]]
        data_tick = np.asarray(arrays["data/tick"]) if "data/tick" in arrays.files else None
    return Bundle(stream, models, unimap, oracle, merged, fsms, list(meta["demos"]),
                  data_labels, float(meta["train_s"]), dict(meta["timings"]), data_tick)

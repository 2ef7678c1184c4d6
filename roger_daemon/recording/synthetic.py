"""Synthetic recorded sessions: a stand-in for the daemon loop, for tests and benchmarks.

:func:`record_synthetic_session` plays the daemon's part on a deterministic stream: each tick
it records the perception and the action, learns the pair with a real model (when the mode
learns), predicts for the perception (when the mode predicts) and records the prediction with
its ``updates``, exactly in the order the daemon does, on a fake 30 Hz clock. The returned
object holds what a correct replay must reproduce.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols import keys
from protocols.messages import (
    Action,
    Control,
    Dims,
    ExpertOutput,
    Perception,
    Prediction,
    Status,
    encode,
)
from roger_daemon.labels import majority_labels
from roger_daemon.recording.metadata import session_metadata
from roger_daemon.recording.replay import Model, default_model_factory
from roger_daemon.recording.timeline import LEARNING_MODES
from roger_daemon.recording.writer import SessionRecorder

__all__ = ["SyntheticSession", "record_synthetic_session", "synthetic_stream"]

TICK_NS = 33_333_333
START_NS = 1_795_000_000_000_000_000  # 2026-11-18, fixed so that file names are stable


@dataclass
class SyntheticSession:
    """What was recorded and what the model did."""

    paths: list[Path]
    dims: Dims
    model: Model
    pairs: list[tuple[int, Any, Any, str]] = field(default_factory=list)  # (tick, x, y, label)
    predictions: list[Prediction] = field(default_factory=list)
    recorder: SessionRecorder | None = None
    checkpoints: dict[int, Any] = field(default_factory=dict)  # n_learned -> state_dict()


def _full_params(pmap: Mapping[str, Any]) -> Any:
    try:
        from roger_daemon.learner import RogerParams
    except ImportError:  # pragma: no cover - learner not installed
        return pmap
    return RogerParams.from_mapping(dict(pmap))


def synthetic_stream(kind: str, n: int, seed: int = 0) -> tuple[Any, Any, list[str]]:
    """``(x (n, d_x), y (n, d_y), labels)`` from the learner's synthetic generators.

    ``"sqrt"``: 1-D two-branch multimap (several experts in ~100 points, fast);
    ``"subtask"``: AIBO-sized 23-D/9-D subtask stream.
    """
    from roger_daemon.learner import synthetic

    if kind == "sqrt":
        s = synthetic.sqrt_multimap(n, seed=seed)
    elif kind == "subtask":
        s = synthetic.subtask_stream(n)
    else:
        raise ValueError(f"stream must be 'sqrt' or 'subtask', got {kind!r}")
    names = ("seek", "trap", "aim", "kick")
    labels = [names[int(v) % len(names)] for v in s.labels]
    return s.x, s.y, labels


def record_synthetic_session(
    directory: str | Path,
    *,
    n_ticks: int = 120,
    robot: str = "sim",
    stream: str = "sqrt",
    seed: int = 7,
    params: Mapping[str, Any] | None = None,
    predict_every: int = 1,
    modes: Mapping[int, str] | None = None,
    resets: tuple[int, ...] = (),
    action_first: tuple[int, ...] = (),
    drop_action: tuple[int, ...] = (),
    garbage: tuple[int, ...] = (),
    status_every: int = 30,
    model_factory: Callable[..., Model] | None = None,
    recorder_kwargs: Mapping[str, Any] | None = None,
    close: bool = True,
    initial_model: Model | None = None,
    tick0: int = 0,
    start_ns: int = START_NS,
    checkpoint_at: tuple[int, ...] = (),
    pre_learn: tuple[tuple[Any, Any, str], ...] = (),
    metadata_extra: Mapping[str, str] | None = None,
) -> SyntheticSession:
    """Record a session of ``n_ticks`` ticks, as the daemon would; see the module doc.

    ``modes`` maps a tick to a mode change (a ``control`` message at the start of that tick);
    ``resets`` are ticks with a ``reset`` control; ``action_first`` ticks send the action before
    the perception; ``drop_action`` ticks have no action; ``garbage`` ticks add an undecodable
    perception payload. ``close=False`` leaves the file open (for crash tests).

    ``initial_model`` continues a model (as a daemon resumed from a checkpoint: the metadata's
    ``start_updates`` is its ``n_learned``); ``tick0`` starts ticks (and the stream) later;
    ``checkpoint_at`` takes ``state_dict()`` snapshots when ``n_learned`` reaches those counts;
    ``pre_learn`` pairs ``(x, y, label)`` are learned first without being recorded (a daemon's
    restored training queue); ``metadata_extra`` overrides or adds metadata keys.
    """
    x, y, labels = synthetic_stream(stream, tick0 + n_ticks, seed=0)
    dims = Dims(int(x.shape[1]), int(y.shape[1]))
    factory = model_factory or default_model_factory
    pmap = dict(params) if params is not None else {}
    mode = "learn+predict"
    meta = session_metadata(
        robot=robot,
        config_text=f"[learner]\n# synthetic session, stream={stream}\n",
        learner_params=_full_params(pmap),
        dims=dims,
        seed=seed,
        mode=mode,
        start_updates=0 if initial_model is None else int(initial_model.n_learned),
        created_by="roger_daemon.recording.synthetic",
    )
    meta.update(metadata_extra or {})
    rec = SessionRecorder(directory, robot=robot, metadata=meta, start_ns=start_ns,
                          **dict(recorder_kwargs or {}))
    model = factory("roger", dims.x, dims.y, pmap, seed) if initial_model is None else (
        initial_model)
    out = SyntheticSession(paths=[], dims=dims, model=model, recorder=rec)
    learned_labels: list[str] = []
    for px, py, plabel in pre_learn:
        model.learn_one(px, py)
        learned_labels.append(plabel)
    k_perc, k_act, k_pred = keys.perception(robot), keys.action(robot), keys.prediction(robot)
    k_ctl, k_status = keys.control(robot), keys.status(robot)

    def put(key: str, payload: bytes, t_ns: int, tick: int) -> None:
        rec.write(key, payload, log_time_ns=t_ns, publish_time_ns=t_ns - 1_000_000,
                  sequence=tick)

    for t in range(tick0, tick0 + n_ticks):
        now = start_ns + (t - tick0) * TICK_NS
        if modes and t in modes:
            mode = modes[t]
            put(k_ctl, encode(Control(robot, t, t / 30, op="mode", mode=mode, stamp_ns=now)),
                now, t)
        if t in resets:
            put(k_ctl, encode(Control(robot, t, t / 30, op="reset", stamp_ns=now)), now, t)
            model = factory("roger", dims.x, dims.y, pmap, seed)
            out.model = model
            learned_labels = []
        perc = encode(Perception(robot, t, t / 30, x=x[t], stamp_ns=now))
        act = encode(Action(robot, t, t / 30, y=y[t], label=labels[t], stamp_ns=now))
        if t in garbage:
            put(k_perc, b"\xc1 not msgpack", now + 1, t)
        order = [(k_act, act), (k_perc, perc)] if t in action_first else [
            (k_perc, perc), (k_act, act)]
        for key, payload in order:
            if key == k_act and t in drop_action:
                continue
            put(key, payload, now + 2_000_000, t)
        if t not in drop_action and mode in LEARNING_MODES:
            model.learn_one(x[t], y[t])
            learned_labels.append(labels[t])
            out.pairs.append((t, x[t], y[t], labels[t]))
            if model.n_learned in checkpoint_at:
                out.checkpoints[model.n_learned] = model.state_dict()
        if mode in ("predict", "learn+predict") and t % predict_every == 0:
            p, mm = model.predict_with_multimap(x[t])  # as the daemon does
            if learned_labels:
                a = np.asarray(model.assignments())[-len(learned_labels):]
                names = majority_labels(a, learned_labels)
            else:
                names = {}
            pred = Prediction(
                robot, t, t / 30, mean=p.mean, var=p.var, expert=p.expert_id,
                multimap=tuple(
                    ExpertOutput(expert=e.expert_id, p=e.gate_prob, mean=e.mean, var=e.var,
                                 n=e.n_points, label=names.get(int(e.expert_id), ""))
                    for e in mm),
                latency_ms=1.0, mode=mode, updates=model.n_learned, stamp_ns=now + 3_000_000,
            )
            out.predictions.append(pred)
            put(k_pred, encode(pred), now + 3_000_000, t)
        if status_every and t % status_every == 0:
            st = Status(robot, t, t / 30, daemon="synthetic", mode=mode, ticks=t,
                        updates=model.n_learned, updates_per_s=30.0, experts=model.n_experts,
                        queue_depth=0, dropped=0, stamp_ns=now + 4_000_000)
            put(k_status, encode(st), now + 4_000_000, t)
        rec.poll(now + 5_000_000)
    if close:
        rec.close()
    out.paths = rec.paths
    return out

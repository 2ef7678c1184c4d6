"""Offline replay: rebuild the learner from a recorded session and compare its predictions.

:func:`replay_session` is the core (used by ``roger replay``, the tests and the experiment).
It reads the session with :func:`~roger_daemon.recording.session_read.read_timeline` (the
daemon's decision records, or the re-paired inputs of a version-1 log), rebuilds the model with
the recorded params and seed, feeds the learned pairs in the daemon's order through the
daemon's own :class:`~roger_daemon.daemon.robot.RobotRuntime`, recomputes every recorded prediction
with it at the same ``updates`` count (in ``updates`` order, then file order), and checks the
checkpoints' model digests the daemon recorded. No Zenoh is involved.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols.messages import Perception
from roger_daemon.config.settings import FSM_MODEL
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.daemon.checkpoint_meta import Counters
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.recording.session_read import read_timeline
from roger_daemon.recording.timeline import (
    LearnedPair,
    ModelCheck,
    RecordedPrediction,
    Segment,
    Timeline,
)
from roger_daemon.replay.checkpoint import (
    load_checkpoint,
    resume_timeline,
    save_checkpoint,
)
from roger_daemon.replay.compare import max_abs_diff, rel_err
from roger_daemon.replay.result import (
    ROUND_OFF_MARGIN,
    DecisionMargin,
    DigestCheck,
    Model,
    ModelFactory,
    PredictionDiff,
    ReplayError,
    ReplayResult,
)

__all__ = [
    "ROUND_OFF_MARGIN",
    "DecisionMargin",
    "DigestCheck",
    "Model",
    "ModelFactory",
    "PredictionDiff",
    "ReplayError",
    "ReplayResult",
    "default_model_factory",
    "load_checkpoint",
    "replay_session",
    "replay_timeline",
    "resume_timeline",
    "save_checkpoint",
]


def default_model_factory(
    kind: str, d_x: int, d_y: int, params: Mapping[str, Any] | None, seed: int | None
) -> Model:
    """The model of ``kind`` from the one registry
    (:func:`roger_daemon.config.models.build_model`; a log that names no kind gets ROGER)."""
    from roger_daemon.config.models import build_model

    model: Model = build_model(kind or "roger", d_x, d_y, params or None, seed)
    return model


def _compare(seg_no: int, rec: RecordedPrediction, rt: RobotRuntime,
             compare_labels: bool) -> PredictionDiff:
    """Recompute one recorded prediction with the daemon's own code (``RobotRuntime.predict``:
    one ``predict_with_multimap`` call, the experts' majority labels) and compare."""
    pred = rt.predict(Perception(rt.robot, rec.tick, 0.0, x=rec.x), 0, lambda: 0)
    rep_ids = [int(e.expert) for e in pred.multimap]
    rec_ids = [int(e.expert) for e in rec.multimap]
    ids_match = sorted(rep_ids) == sorted(rec_ids)
    mm_abs = 0.0
    rel = max(rel_err(pred.mean, rec.mean), rel_err(pred.var, rec.var))
    sizes = True
    labels_ok: bool | None = True if compare_labels and rec.multimap and rt.n_codes else None
    if ids_match:
        by_id = {int(e.expert): e for e in pred.multimap}
        for r in rec.multimap:
            e = by_id[int(r.expert)]
            mm_abs = max(mm_abs, abs(e.p - r.p), max_abs_diff(e.mean, r.mean),
                         max_abs_diff(e.var, r.var))
            rel = max(rel, rel_err(e.p, r.p), rel_err(e.mean, r.mean), rel_err(e.var, r.var))
            sizes = sizes and e.n == r.n
            if labels_ok is not None:
                labels_ok = labels_ok and e.label == r.label
    else:
        mm_abs = rel = math.inf
        sizes = False
        labels_ok = None if labels_ok is None else False
    return PredictionDiff(
        segment=seg_no,
        tick=rec.tick,
        updates=rec.updates,
        log_time_ns=rec.log_time_ns,
        mean_abs=max_abs_diff(pred.mean, rec.mean),
        var_abs=max_abs_diff(pred.var, rec.var),
        expert_recorded=rec.expert,
        expert_replayed=pred.expert,
        multimap_abs=mm_abs,
        multimap_ids_match=ids_match,
        sizes_match=sizes,
        labels_match=labels_ok,
        rel=rel,
        margin=_prediction_margin(seg_no, rt.model, [e.p for e in pred.multimap]),
    )


def _gap(values: Iterable[float]) -> float:
    """Gap between the largest value and the largest *different* one (``inf``: none); exact
    ties are resolved by index the same way on every machine, so they are not near-ties."""
    v = sorted(set(values), reverse=True)
    return v[0] - v[1] if len(v) > 1 else math.inf


def _prediction_margin(seg_no: int, model: Model, probs: Sequence[float]) -> DecisionMargin:
    """The closer of the two decisions of a prediction: which particle is the MAP one, and
    which of its experts (or the empty expert, the rest of the gate mass) is chosen."""
    choice = _gap([*probs, max(0.0, 1.0 - sum(probs))])
    logw = getattr(model, "particle_log_weights", None)
    best = _gap(np.asarray(logw()).tolist()) if logw is not None else math.inf
    kind, value = min((("expert_choice", choice), ("map_particle", best)), key=lambda kv: kv[1])
    return DecisionMargin(seg_no, int(model.n_learned), kind, value)


@dataclass
class _Replay:
    """The state of one replay: the daemon's runtime fed the log, and what was found."""

    rt: RobotRuntime
    compare_labels: bool
    progress: Callable[[int], None] | None
    diffs: list[PredictionDiff] = field(default_factory=list)
    margins: list[DecisionMargin] = field(default_factory=list)
    unreplayable: int = 0
    digests: list[DigestCheck] = field(default_factory=list)
    #: the session's own model kind: a session of plain ROGER replayed with its transitions
    #: (``--model roger+fsm``) checks the experts' part of the state (roger_daemon/fsm/online.py)
    recorded_kind: str = "roger"

    def segment(self, seg_no: int, seg: Segment) -> None:
        """Learn the segment's pairs through the runtime, evaluating the recorded predictions
        at the model state they were computed on and checking the recorded model digests."""
        rt = self.rt
        preds = sorted(seg.predictions, key=lambda p: p.updates)  # stable: file order
        checks = {c.updates: c for c in seg.digests}
        pi = 0

        def evaluate(upto: int) -> None:
            nonlocal pi
            while pi < len(preds) and preds[pi].updates <= upto:
                rec = preds[pi]
                pi += 1
                if rec.updates < seg.start_updates:
                    self.unreplayable += 1
                    continue
                self.diffs.append(_compare(seg_no, rec, rt, self.compare_labels))
            if upto in checks:
                self._check_digest(seg_no, checks.pop(upto))

        for pair in seg.pairs:
            evaluate(rt.updates)
            errors = rt.learn_errors
            rt.enqueue_recovered(pair.x, pair.y, pair.label, pair.tick)
            rt.learn_one()
            step = getattr(rt.model, "last_margins", None)
            if rt.learn_errors == errors and step:
                kind, value = min(step.items(), key=lambda kv: kv[1])
                self.margins.append(DecisionMargin(seg_no, rt.updates, kind, float(value)))
            if self.progress is not None:
                self.progress(1)
        evaluate(rt.updates)
        self.unreplayable += len(preds) - pi  # computed after pairs the log does not have

    def check_start(self, tl: Timeline) -> None:
        """Is the model the replay starts from the one the session started with? (Its
        digest, metadata ``start_model_digest``; not recorded by older daemons.)"""
        want = tl.info.raw.get("start_model_digest", "")
        seg = tl.segments[0]
        if want and seg.start_updates == tl.info.start_updates:  # not a mid-session resume
            self._check_digest(0, ModelCheck(seg.start_updates, want, ""))

    def _check_digest(self, seg_no: int, check: ModelCheck) -> None:
        model = self.rt.model
        experts = getattr(model, "experts_state", None)
        state = experts() if experts is not None and self.recorded_kind != FSM_MODEL \
            else model.state_dict()
        digest = array_digest(dict(state))
        self.digests.append(DigestCheck(seg_no, check.updates, check.digest == digest))


def _start(rt: RobotRuntime, tl: Timeline, initial_model: Model | None,
           initial_pairs: Sequence[LearnedPair], warnings: list[str]) -> Segment | None:
    """The first segment as it replays (the checkpoint's queue in front), with ``rt`` holding
    the model it starts from; ``None`` if it cannot be replayed (no checkpoint given)."""
    seg = tl.segments[0]
    if seg.start_updates == 0 and seg.queued == 0:
        rt.model = rt.make_model()
        return seg
    if initial_model is None:
        warnings.append(
            f"session resumed from a checkpoint at {seg.start_updates} updates"
            + (f" with {seg.queued} queued pairs" if seg.queued else "")
            + f" ({tl.info.raw.get('checkpoint', '?')}); give the checkpoint to replay it")
        return None
    if int(initial_model.n_learned) != seg.start_updates:
        raise ReplayError(f"initial model has learned {initial_model.n_learned} pairs, the "
                          f"session started at {seg.start_updates}")
    rt.model = initial_model
    # the labels of the pairs it learned before are unknown here: the empty label, which
    # never wins a majority (roger_daemon.labels); nothing queued
    unknown = RobotState.from_labels([""] * int(initial_model.n_learned), vocab=[""])
    rt.restore(unknown.to_arrays(rt.dims), Counters())
    if tl.decisions:  # a version-2 log names the queued pairs it learned as its own
        return seg
    if len(initial_pairs) != seg.queued:
        warnings.append(
            f"the session learned {seg.queued} queued pairs from its checkpoint first; "
            f"the checkpoint given holds {len(initial_pairs)}")
    if initial_pairs:  # the checkpoint's queue: learned before this session's pairs
        seg = Segment(seg.start_updates, seg.after_reset, [*initial_pairs, *seg.pairs],
                      seg.predictions, digests=seg.digests)
    return seg


def replay_timeline(
    tl: Timeline,
    *,
    params: Mapping[str, Any] | None = None,
    seed: int | None = None,
    model_kind: str | None = None,
    initial_model: Model | None = None,
    initial_pairs: Sequence[LearnedPair] = (),
    model_factory: ModelFactory | None = None,
    compare_labels: bool = True,
    progress: Callable[[int], None] | None = None,
) -> ReplayResult:
    """Replay an already read :class:`Timeline` (see :func:`replay_session`).

    The pairs are fed through the daemon's own :class:`~roger_daemon.daemon.robot.RobotRuntime`
    (``enqueue_recovered`` + ``learn_one``, ``reset`` between segments, ``predict`` for each
    recorded prediction), as start-up recovery does.
    """
    info = tl.info
    warnings: list[str] = []
    if tl.dims is None:
        raise ReplayError("no dims in the metadata and no valid perception/action to infer them")
    dims = tl.dims
    kind = model_kind or info.model
    use_params = dict(params) if params is not None else info.learner_params
    use_seed = seed if seed is not None else info.seed
    if use_seed is None:
        warnings.append("no seed recorded and none given: using seed 0 (replay may differ)")
        use_seed = 0
    factory = model_factory or default_model_factory
    rt = RobotRuntime(tl.robot, dims, None,
                      lambda: factory(kind, dims.x, dims.y, use_params, use_seed),
                      queue_size=2**31 - 1, pair_window=tl.pair_window)
    run = _Replay(rt, compare_labels, progress, recorded_kind=info.model)
    for i, seg in enumerate(tl.segments):
        first = _start(rt, tl, initial_model, initial_pairs, warnings) if i == 0 else None
        if i > 0:
            rt.reset()
        elif first is None:
            run.unreplayable += len(seg.predictions)
            continue
        if i == 0:
            run.check_start(tl)
        run.segment(i, first or seg)
    _warn(tl, rt, run, warnings)
    last = tl.segments[-1]
    model = rt.model
    labels = [p.label for p in last.pairs] if not rt.learn_errors else []
    assignments = (np.asarray(model.assignments(), dtype=np.int64) if model is not None
                   else np.zeros(0, dtype=np.int64))
    return ReplayResult(
        files=tl.files, info=info, robot=tl.robot, model_kind=kind, params=use_params,
        seed=use_seed, model=model, pairs=last.pairs, labels=labels, assignments=assignments,
        expert_labels=rt.expert_labels() if model is not None and rt.n_codes else {},
        diffs=run.diffs, unreplayable=run.unreplayable, timeline=tl, warnings=warnings,
        learn_errors=rt.learn_errors, margins=run.margins, digests=run.digests,
    )


def _warn(tl: Timeline, rt: RobotRuntime, run: _Replay, warnings: list[str]) -> None:
    if tl.incomplete_files:
        warnings.append(f"incomplete files (no footer): {tl.incomplete_files}")
    if tl.unexplained_drops:
        warnings.append(
            f"the daemon dropped {tl.unexplained_drops} pairs (training queue full) that the log "
            "does not name, so predictions after the first drop may differ"
        )
    if rt.learn_errors:
        warnings.append(f"the learner rejected {rt.learn_errors} pairs (skipped, as the daemon "
                        "does)")
    bad = [d for d in run.digests if not d.match]
    if bad:
        warnings.append(f"the replayed model differs from the daemon's at {len(bad)} of "
                        f"{len(run.digests)} recorded checkpoint digests (first: segment "
                        f"{bad[0].segment}, {bad[0].updates} updates)")


def replay_session(
    path: str | Path | Iterable[str | Path],
    params: Mapping[str, Any] | None = None,
    *,
    seed: int | None = None,
    robot: str | None = None,
    model_kind: str | None = None,
    initial_model: Model | None = None,
    initial_pairs: Sequence[LearnedPair] = (),
    model_factory: ModelFactory | None = None,
    compare_labels: bool = True,
    progress: Callable[[int], None] | None = None,
) -> ReplayResult:
    """Replay one session (a file, or its parts in order) offline.

    Parameters
    ----------
    path
        The MCAP file, or the session's parts in order (footer-less files are read up to their
        last complete chunk).
    params
        Learner params (e.g. a config's ``[learner]`` table); default: the recorded ones.
    seed
        Model seed; default: the recorded one.
    robot
        Which robot to replay; default: the metadata's (needed for multi-robot ``roger record``
        files).
    model_kind
        ``"roger"`` or ``"unimap"``; default: the recorded one.
    initial_model
        The model the session started from, when it resumed from a checkpoint
        (metadata ``start_updates`` > 0); see :func:`load_checkpoint`.
    initial_pairs
        Pairs queued in that checkpoint (learned before the session's own pairs).
    model_factory
        Builds the model (default: :func:`default_model_factory`).
    compare_labels
        Also compare the multimaps' majority labels (reported; not part of :meth:`ReplayResult.ok`).
    progress
        Called with 1 after each learned pair.
    """
    paths = [path] if isinstance(path, str | Path) else list(path)
    tl = read_timeline(paths, robot=robot)
    return replay_timeline(
        tl,
        params=params,
        seed=seed,
        model_kind=model_kind,
        initial_model=initial_model,
        initial_pairs=initial_pairs,
        model_factory=model_factory,
        compare_labels=compare_labels,
        progress=progress,
    )

"""Offline replay: rebuild the learner from a recorded session and compare its predictions.

:func:`replay_session` is the core (used by ``roger replay``, the tests and the experiment).
It reads the session with :func:`~roger_daemon.recording.session_read.read_timeline`, rebuilds the
model with the recorded params and seed, learns the recorded pairs in the daemon's order, and
recomputes every recorded prediction from the model at the same ``updates`` count (predictions
are evaluated in ``updates`` order, then file order, calling
``predict_with_multimap`` as the daemon does). No Zenoh is involved.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.labels import majority_labels, majority_labels_coded
from roger_daemon.recording.compare import max_abs_diff, rel_err
from roger_daemon.recording.replay_checkpoint import (
    load_checkpoint,
    resume_timeline,
    save_checkpoint,
)
from roger_daemon.recording.replay_result import (
    ROUND_OFF_MARGIN,
    DecisionMargin,
    Model,
    ModelFactory,
    PredictionDiff,
    ReplayError,
    ReplayResult,
)
from roger_daemon.recording.session_read import read_timeline
from roger_daemon.recording.timeline import (
    LearnedPair,
    RecordedPrediction,
    Segment,
    Timeline,
)

__all__ = [
    "ROUND_OFF_MARGIN",
    "DecisionMargin",
    "Model",
    "ModelFactory",
    "PredictionDiff",
    "ReplayError",
    "ReplayResult",
    "default_model_factory",
    "load_checkpoint",
    "majority_labels",
    "replay_session",
    "replay_timeline",
    "resume_timeline",
    "save_checkpoint",
]


def default_model_factory(
    kind: str, d_x: int, d_y: int, params: Mapping[str, Any] | None, seed: int | None
) -> Model:
    """Build ``Roger`` (or ``UnimapGP`` for model ``"unimap"``) from ``roger_daemon.learner``."""
    from roger_daemon import learner

    p = learner.RogerParams.from_mapping(dict(params)) if params else learner.RogerParams()
    cls = learner.UnimapGP if kind == "unimap" else learner.Roger
    model: Model = cls(d_x=d_x, d_y=d_y, params=p, seed=seed)
    return model


def _compare(
    seg_no: int,
    rec: RecordedPrediction,
    model: Model,
    labels_now: dict[int, str] | None,
) -> PredictionDiff:
    pred, mm = model.predict_with_multimap(rec.x)  # as the daemon does, one call per tick
    rep_ids = [int(e.expert_id) for e in mm]
    rec_ids = [int(e.expert) for e in rec.multimap]
    ids_match = sorted(rep_ids) == sorted(rec_ids)
    mm_abs = 0.0
    rel = max(rel_err(pred.mean, rec.mean), rel_err(pred.var, rec.var))
    sizes = True
    labels_ok: bool | None = None
    if ids_match:
        by_id = {int(e.expert_id): e for e in mm}
        if labels_now is not None:
            labels_ok = True
        for r in rec.multimap:
            e = by_id[int(r.expert)]
            mm_abs = max(
                mm_abs,
                abs(float(e.gate_prob) - r.p),
                max_abs_diff(e.mean, r.mean),
                max_abs_diff(e.var, r.var),
            )
            rel = max(rel, rel_err(float(e.gate_prob), r.p), rel_err(e.mean, r.mean),
                      rel_err(e.var, r.var))
            sizes = sizes and int(e.n_points) == r.n
            if labels_now is not None:
                labels_ok = labels_ok and labels_now.get(int(r.expert), "") == r.label
    else:
        mm_abs = rel = math.inf
        sizes = False
    return PredictionDiff(
        segment=seg_no,
        tick=rec.tick,
        updates=rec.updates,
        log_time_ns=rec.log_time_ns,
        mean_abs=max_abs_diff(pred.mean, rec.mean),
        var_abs=max_abs_diff(pred.var, rec.var),
        expert_recorded=rec.expert,
        expert_replayed=int(pred.expert_id),
        multimap_abs=mm_abs,
        multimap_ids_match=ids_match,
        sizes_match=sizes,
        labels_match=labels_ok,
        rel=rel,
        margin=_prediction_margin(seg_no, model, mm),
    )


def _gap(values: Iterable[float]) -> float:
    """Gap between the largest value and the largest *different* one (``inf``: none); exact
    ties are resolved by index the same way on every machine, so they are not near-ties."""
    v = sorted(set(values), reverse=True)
    return v[0] - v[1] if len(v) > 1 else math.inf


def _prediction_margin(seg_no: int, model: Model, mm: Sequence[Any]) -> DecisionMargin:
    """The closer of the two decisions of a prediction: which particle is the MAP one, and
    which of its experts (or the empty expert, the rest of the gate mass) is chosen."""
    probs = [float(e.gate_prob) for e in mm]
    choice = _gap([*probs, max(0.0, 1.0 - sum(probs))])
    logw = getattr(model, "particle_log_weights", None)
    best = _gap(np.asarray(logw()).tolist()) if logw is not None else math.inf
    kind, value = min((("expert_choice", choice), ("map_particle", best)), key=lambda kv: kv[1])
    return DecisionMargin(seg_no, int(model.n_learned), kind, value)


#: What the daemon catches around ``learn_one`` (the pair is skipped, the loop goes on).
LEARN_ERRORS: tuple[type[BaseException], ...] = (ValueError, ArithmeticError,
                                                  np.linalg.LinAlgError)


def _replay_segment(
    seg_no: int,
    seg: Segment,
    model: Model,
    diffs: list[PredictionDiff],
    *,
    compare_labels: bool,
    progress: Callable[[int], None] | None,
    margins: list[DecisionMargin] | None = None,
) -> tuple[int, int]:
    """Learn the segment's pairs, evaluating predictions on the way.

    Returns (unreplayable predictions, learn errors).
    """
    preds = sorted(seg.predictions, key=lambda p: p.updates)  # stable: file order within a count
    labels: list[str] = []
    # the labels as codes into ``vocab`` too, so that labelling the experts at each prediction
    # is one vectorised pass (the rule is :func:`majority_labels_coded`'s either way)
    vocab: dict[str, int] = {}
    codes = np.zeros(len(seg.pairs), dtype=np.int64)
    unreplayable = 0
    errors = 0
    pi = 0
    label_budget = compare_labels and len(seg.pairs) * max(len(preds), 1) <= 200_000_000

    def evaluate(upto: int) -> None:
        nonlocal pi, unreplayable
        while pi < len(preds) and preds[pi].updates <= upto:
            rec = preds[pi]
            pi += 1
            if rec.updates < seg.start_updates:
                unreplayable += 1
                continue
            labels_now = None
            if label_budget and rec.multimap and labels:
                labels_now = majority_labels_coded(
                    np.asarray(model.assignments())[-len(labels):], codes[:len(labels)],
                    list(vocab))
            diffs.append(_compare(seg_no, rec, model, labels_now))

    learned = seg.start_updates
    for pair in seg.pairs:
        evaluate(learned)
        try:
            model.learn_one(pair.x, pair.y)
        except LEARN_ERRORS:
            errors += 1
        else:
            learned += 1
            codes[len(labels)] = vocab.setdefault(pair.label, len(vocab))
            labels.append(pair.label)
            step = getattr(model, "last_margins", None)
            if margins is not None and step:
                kind, value = min(step.items(), key=lambda kv: kv[1])
                margins.append(DecisionMargin(seg_no, learned, kind, float(value)))
        if progress is not None:
            progress(1)
    evaluate(learned)
    unreplayable += len(preds) - pi  # computed after pairs the log does not have
    return unreplayable, errors


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
    """Replay an already read :class:`Timeline` (see :func:`replay_session`)."""
    info = tl.info
    warnings: list[str] = []
    if tl.dims is None:
        raise ReplayError("no dims in the metadata and no valid perception/action to infer them")
    kind = model_kind or info.model
    use_params = dict(params) if params is not None else info.learner_params
    use_seed = seed if seed is not None else info.seed
    if use_seed is None:
        warnings.append("no seed recorded and none given: using seed 0 (replay may differ)")
        use_seed = 0
    factory = model_factory or default_model_factory
    diffs: list[PredictionDiff] = []
    margins: list[DecisionMargin] = []
    unreplayable = 0
    learn_errors = 0
    model: Model | None = None
    for i, seg in enumerate(tl.segments):
        if i == 0 and (seg.start_updates > 0 or seg.queued > 0):
            if initial_model is None:
                warnings.append(
                    f"session resumed from a checkpoint at {seg.start_updates} updates"
                    + (f" with {seg.queued} queued pairs" if seg.queued else "")
                    + f" ({info.raw.get('checkpoint', '?')}); give the checkpoint to replay it"
                )
                unreplayable += len(seg.predictions)
                model = None
                continue
            if int(initial_model.n_learned) != seg.start_updates:
                raise ReplayError(
                    f"initial model has learned {initial_model.n_learned} pairs, the session "
                    f"started at {seg.start_updates}"
                )
            model = initial_model
            if len(initial_pairs) != seg.queued:
                warnings.append(
                    f"the session learned {seg.queued} queued pairs from its checkpoint first; "
                    f"the checkpoint given holds {len(initial_pairs)}"
                )
            if initial_pairs:  # the checkpoint's queue: learned before this session's pairs
                seg = Segment(seg.start_updates, seg.after_reset,
                              [*initial_pairs, *seg.pairs], seg.predictions)
        else:
            model = factory(kind, tl.dims.x, tl.dims.y, use_params, use_seed)
        lost, errs = _replay_segment(
            i, seg, model, diffs, compare_labels=compare_labels, progress=progress,
            margins=margins,
        )
        unreplayable += lost
        learn_errors += errs
    last = tl.segments[-1]
    labels = [p.label for p in last.pairs]
    if learn_errors:
        labels = []  # which pairs were rejected is not kept; no label mapping then
    if model is not None:
        assignments = np.asarray(model.assignments(), dtype=np.int64)
        own = assignments[-len(labels):] if labels else assignments[:0]
        expert_labels = majority_labels(own, labels) if labels and len(own) == len(labels) else {}
    else:
        assignments = np.zeros(0, dtype=np.int64)
        expert_labels = {}
    if tl.incomplete_files:
        warnings.append(f"incomplete files (no footer): {tl.incomplete_files}")
    if tl.unexplained_drops:
        warnings.append(
            f"the daemon dropped {tl.unexplained_drops} pairs (training queue full) that the log "
            "does not name, so predictions after the first drop may differ"
        )
    if learn_errors:
        warnings.append(f"the learner rejected {learn_errors} pairs (skipped, as the daemon does)")
    return ReplayResult(
        files=tl.files,
        info=info,
        robot=tl.robot,
        model_kind=kind,
        params=use_params,
        seed=use_seed,
        model=model,
        pairs=last.pairs,
        labels=labels,
        assignments=assignments,
        expert_labels=expert_labels,
        diffs=diffs,
        unreplayable=unreplayable,
        timeline=tl,
        warnings=warnings,
        learn_errors=learn_errors,
        margins=margins,
    )


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

"""Offline replay: rebuild the learner from a recorded session and compare its predictions.

:func:`replay_session` is the core (used by ``roger replay``, the tests and the experiment).
It reads the session with :func:`~roger_daemon.recording.timeline.read_timeline`, rebuilds the
model with the recorded params and seed, learns the recorded pairs in the daemon's order, and
recomputes every recorded prediction from the model at the same ``updates`` count (predictions
are evaluated in ``updates`` order, then file order, calling
``predict_with_multimap`` as the daemon does). No Zenoh is involved.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.labels import majority_labels
from roger_daemon.learner.protocol import Learner
from roger_daemon.recording.compare import max_abs_diff, rel_err
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.timeline import (
    LearnedPair,
    RecordedPrediction,
    Segment,
    Timeline,
    read_timeline,
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


class ReplayError(RuntimeError):
    """The session cannot be replayed as asked (e.g. it resumed from a checkpoint not given)."""


#: What replay rebuilds and drives: the learner contract (docs/learner-api.md), one owner.
Model = Learner


#: ``factory(model_kind, d_x, d_y, params_mapping_or_None, seed_or_None) -> Model``
ModelFactory = Callable[[str, int, int, "Mapping[str, Any] | None", "int | None"], Model]


def default_model_factory(
    kind: str, d_x: int, d_y: int, params: Mapping[str, Any] | None, seed: int | None
) -> Model:
    """Build ``Roger`` (or ``UnimapGP`` for model ``"unimap"``) from ``roger_daemon.learner``."""
    from roger_daemon import learner

    p = learner.RogerParams.from_mapping(dict(params)) if params else learner.RogerParams()
    cls = learner.UnimapGP if kind == "unimap" else learner.Roger
    model: Model = cls(d_x=d_x, d_y=d_y, params=p, seed=seed)
    return model


@dataclass(frozen=True)
class DecisionMargin:
    """How close one discrete decision of the replayed learner was to going the other way.

    ``kind``: ``"resampling"`` (normalised particle weight against a threshold or stratified
    point), ``"novelty"`` (the SOGP's projection residual against its threshold, in units of
    k*), ``"map_particle"`` (log-weight gap of the best two particles) or ``"expert_choice"``
    (gate-probability gap of the best two experts). A margin near round-off (below
    ``ROUND_OFF_MARGIN``) can flip on another BLAS kernel; a larger one cannot.
    """

    segment: int
    updates: int  # the learner's n_learned after the step (or at the prediction)
    kind: str
    value: float


#: A decision this close to its boundary may flip under another kernel's round-off: the floats
#: differ by up to ~5e-7 relative across kernels with the default learner (docs/reproducibility.md).
ROUND_OFF_MARGIN = 1e-6


@dataclass(frozen=True)
class PredictionDiff:
    """One recorded prediction against its recomputation."""

    segment: int
    tick: int
    updates: int
    log_time_ns: int
    mean_abs: float  # max |mean_replayed - mean_recorded|
    var_abs: float  # max |var_replayed - var_recorded|
    expert_recorded: int
    expert_replayed: int
    multimap_abs: float  # max |p|,|mean|,|var| difference over the experts; inf if ids differ
    multimap_ids_match: bool
    sizes_match: bool  # points per expert (the multimap's n) equal
    labels_match: bool | None  # majority labels equal (None: not compared)
    rel: float = 0.0  # max relative error over every float (compare.rel_err); inf if ids differ
    margin: DecisionMargin | None = None  # the replayed prediction's closest decision

    @property
    def expert_match(self) -> bool:
        """Same chosen expert id."""
        return self.expert_recorded == self.expert_replayed

    @property
    def structure_match(self) -> bool:
        """Same chosen expert, same multimap expert ids and sizes (compared exactly)."""
        return self.expert_match and self.multimap_ids_match and self.sizes_match

    @property
    def bit_identical(self) -> bool:
        """The same structure and every float equal to the last bit."""
        return self.structure_match and self.rel == 0.0

    def ok(self, tolerance: float) -> bool:
        """The same structure and every float within relative error ``tolerance``."""
        return self.structure_match and self.rel <= tolerance

    def what(self) -> str:
        """What differs, in words (the first structural difference, else the float error)."""
        if not self.expert_match:
            return f"chosen expert {self.expert_replayed} (recorded {self.expert_recorded})"
        if not self.multimap_ids_match:
            return "the multimap's experts differ"
        if not self.sizes_match:
            return "the experts' sizes differ"
        return f"relative float error {self.rel:.3g}"


@dataclass
class ReplayResult:
    """What a replay rebuilt and how it compares with the recording."""

    files: list[Path]
    info: SessionInfo
    robot: str
    model_kind: str
    params: dict[str, Any] | None
    seed: int | None
    model: Model | None  # the final model (last segment)
    pairs: list[LearnedPair]  # learned pairs of the last segment, in order
    labels: list[str]  # the action label of each learned pair (last segment)
    assignments: npt.NDArray[np.int64]  # final model's expert of every learned pair
    expert_labels: dict[int, str]  # majority label per expert of the final model
    diffs: list[PredictionDiff]
    unreplayable: int  # predictions whose model state the log cannot reproduce
    timeline: Timeline
    warnings: list[str] = field(default_factory=list)
    learn_errors: int = 0  # pairs the learner rejected (skipped, as the daemon does)
    margins: list[DecisionMargin] = field(default_factory=list)  # per learned pair

    @property
    def n_experts(self) -> int:
        """Experts of the final model."""
        return int(self.model.n_experts) if self.model is not None else 0

    @property
    def n_learned(self) -> int:
        """``n_learned`` of the final model."""
        return int(self.model.n_learned) if self.model is not None else 0

    def max_mean_diff(self) -> float:
        """Max abs difference of means over all compared predictions (0 if none)."""
        return max((d.mean_abs for d in self.diffs), default=0.0)

    def max_var_diff(self) -> float:
        """Max abs difference of variances over all compared predictions (0 if none)."""
        return max((d.var_abs for d in self.diffs), default=0.0)

    def max_multimap_diff(self) -> float:
        """Max abs difference inside the multimaps (inf if some expert ids differ)."""
        return max((d.multimap_abs for d in self.diffs), default=0.0)

    def max_rel_err(self) -> float:
        """Max relative error over every compared float (inf if some structure differs)."""
        return max((d.rel for d in self.diffs), default=0.0)

    def bit_identical(self) -> bool:
        """Every recorded prediction recomputed to the last bit (and none unreplayable)."""
        return self.unreplayable == 0 and all(d.bit_identical for d in self.diffs)

    def verdict(self, tolerance: float) -> str:
        """``"bit-identical"``, ``"within tolerance"`` or ``"MISMATCH"``."""
        if self.bit_identical():
            return "bit-identical"
        return "within tolerance" if self.ok(tolerance) else "MISMATCH"

    def first_divergence(self) -> dict[str, Any] | None:
        """The first prediction that is not bit-identical: where, and what differs.

        ``kind`` is ``"structure"`` when a discrete outcome differs (chosen expert, multimap
        experts, sizes), else ``"float"``. The first *structural* divergence is reported
        separately, since round-off elsewhere can flip a near-tied decision later on.
        """
        first = next((d for d in self.diffs if not d.bit_identical), None)
        if first is None:
            return None
        out = _where(first)
        k = next((i for i, d in enumerate(self.diffs) if not d.structure_match), None)
        out["first_structure_divergence"] = None if k is None else {
            **_where(self.diffs[k]), **self._closest_decision(k)}
        return out

    def _closest_decision(self, k: int) -> dict[str, Any]:
        """The replayed learner's closest decision between the last structurally equal
        prediction before ``diffs[k]`` and ``diffs[k]`` itself: could round-off explain it?"""
        d = self.diffs[k]
        since = next((p.updates for p in reversed(self.diffs[:k])
                      if p.segment == d.segment and p.structure_match), -1)
        cands = [m for m in self.margins
                 if m.segment == d.segment and since < m.updates <= d.updates]
        if d.margin is not None:
            cands.append(d.margin)
        if not cands:
            return {"closest_decision": None, "round_off_can_explain": False}
        m = min(cands, key=lambda c: c.value)
        return {"closest_decision": {"kind": m.kind, "updates": m.updates, "margin": m.value},
                "round_off_can_explain": m.value < ROUND_OFF_MARGIN}

    def mismatches(self, tolerance: float) -> list[PredictionDiff]:
        """Predictions that do not reproduce within ``tolerance``."""
        return [d for d in self.diffs if not d.ok(tolerance)]

    def ok(self, tolerance: float) -> bool:
        """Every recorded prediction reproduced and none left unreplayable."""
        return self.unreplayable == 0 and not self.mismatches(tolerance)

    def summary(self, tolerance: float) -> dict[str, Any]:
        """JSON-ready report."""
        bad = self.mismatches(tolerance)
        tl = self.timeline
        sizes = {}
        if self.model is not None:
            sizes = {str(k): int(v) for k, v in dict(self.model.expert_sizes()).items()}

        def _f(v: float) -> float | str:
            return v if math.isfinite(v) else "inf"

        return {
            "files": [str(p) for p in self.files],
            "robot": self.robot,
            "model": self.model_kind,
            "seed": self.seed,
            "params": self.params,
            "pairs_learned": len(self.pairs),
            "n_learned": self.n_learned,
            "n_experts": self.n_experts,
            "expert_sizes": sizes,
            "expert_labels": {str(k): v for k, v in sorted(self.expert_labels.items())},
            "segments": len(tl.segments),
            "predictions_compared": len(self.diffs),
            "predictions_unreplayable": self.unreplayable,
            "max_abs_diff_mean": _f(self.max_mean_diff()),
            "max_abs_diff_var": _f(self.max_var_diff()),
            "max_abs_diff_multimap": _f(self.max_multimap_diff()),
            "expert_mismatches": sum(not d.expert_match for d in self.diffs),
            "multimap_id_mismatches": sum(not d.multimap_ids_match for d in self.diffs),
            "size_mismatches": sum(not d.sizes_match for d in self.diffs),
            "label_mismatches": sum(d.labels_match is False for d in self.diffs),
            "max_rel_err": _f(self.max_rel_err()),
            "tolerance": tolerance,
            "verdict": self.verdict(tolerance),
            "first_divergence": self.first_divergence(),
            "mismatches": len(bad),
            "first_mismatch": None
            if not bad
            else {"tick": bad[0].tick, "updates": bad[0].updates, "segment": bad[0].segment},
            "ok": self.ok(tolerance),
            "invalid_messages": dict(tl.invalid),
            "ignored_while_not_learning": tl.ignored_not_learning,
            "pair_window": tl.pair_window,
            "daemon_dropped_pairs": tl.daemon_dropped,
            "dropped_pairs_recorded": tl.dropped_recorded,
            "learn_errors": self.learn_errors,
            "unpaired": {"perceptions": tl.unpaired[0], "actions": tl.unpaired[1]},
            "predictions_without_query": tl.predictions_without_query,
            "incomplete_files": tl.incomplete_files,
            "file_errors": tl.file_errors,
            "warnings": self.warnings,
        }


def _where(d: PredictionDiff) -> dict[str, Any]:
    return {"tick": d.tick, "updates": d.updates, "segment": d.segment,
            "kind": "float" if d.structure_match else "structure", "what": d.what(),
            "rel_err": d.rel if math.isfinite(d.rel) else "inf"}


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
                labels_now = majority_labels(np.asarray(model.assignments())[-len(labels):],
                                             labels)
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


def load_checkpoint(path: str | Path) -> tuple[Model, list[LearnedPair], dict[str, Any]]:
    """``(model, queued pairs, meta)`` from a daemon checkpoint (``roger_daemon.checkpoint``),
    or from a plain ``.npz`` of a ``state_dict()`` (no queue, empty meta). Never unpickles."""
    from roger_daemon.learner import load_model

    try:
        from roger_daemon.checkpoint import CheckpointError, read_checkpoint
    except ImportError:  # pragma: no cover - daemon package absent
        read_checkpoint = None  # type: ignore[assignment]
        CheckpointError = Exception  # type: ignore[assignment,misc]  # noqa: N806
    if read_checkpoint is not None:
        try:
            ck = read_checkpoint(Path(path))
        except CheckpointError:
            ck = None
        if ck is not None:
            model: Model = load_model(ck.model)
            d = ck.daemon
            pairs: list[LearnedPair] = []
            if "queue_ticks" in d:
                vocab = [str(v) for v in d.get("label_vocab", np.zeros(0, "<U1")).tolist()]
                start = int(model.n_learned)
                for i, (x, y, code, tick) in enumerate(zip(
                        d["queue_x"], d["queue_y"], d["queue_labels"], d["queue_ticks"],
                        strict=True)):
                    label = vocab[int(code)] if 0 <= int(code) < len(vocab) else ""
                    pairs.append(LearnedPair(start + i, int(tick), np.array(x, dtype=float),
                                             np.array(y, dtype=float), label, 0))
            return model, pairs, dict(ck.meta)
    with np.load(path, allow_pickle=False) as z:
        state = {k: z[k] for k in z.files}
    return load_model(state), [], {}


def resume_timeline(
    tl: Timeline,
    files: Sequence[str | Path],
    *,
    learned: int,
    meta: Mapping[str, Any],
    queued: Sequence[LearnedPair] = (),
) -> tuple[Timeline, list[str]]:
    """The part of a session after a checkpoint taken *during* it (a crash's last checkpoint).

    The result has one segment starting at ``learned``: the checkpoint's queued pairs and the
    pairs logged after them (log-tail catch-up, checked against the checkpoint's last learned
    tick), with the recorded predictions computed from that point on. Replay it with the
    checkpoint's model as ``initial_model`` (no ``initial_pairs``: they are in the segment).
    Returns the original timeline and a warning when the history restarted after the
    checkpoint (a reset): that part replays without it.
    """
    from roger_daemon.recording.catchup import log_tail

    same = str(meta.get("session_id", "") or "") == tl.info.session_id
    counters = meta.get("counters", {}) if isinstance(meta.get("counters"), dict) else {}
    last_tick = counters.get("last_learned_tick")
    tail = log_tail(
        list(files), learned=learned, robot=tl.robot, dims=tl.dims,
        last_tick=last_tick if isinstance(last_tick, int) else None,
        from_session=tl.info.session_id if same and tl.info.session_id else None,
        segment=int(meta.get("session_segment", 0) or 0) if same else 0,
        queue=queued,
    )
    if tail.fresh:
        return tl, ["the session reset its model after the checkpoint: the model after the "
                    "reset is replayed from a fresh model, without the checkpoint"]
    k = int(meta.get("session_segment", 0) or 0) if same else len(tl.segments) - 1
    k = min(max(k, 0), len(tl.segments) - 1)
    preds = [p for p in tl.segments[k].predictions if p.updates >= learned]
    seg = Segment(start_updates=learned, after_reset=False, pairs=list(tail.pairs),
                  predictions=preds)
    notes = list(tail.notes)
    return replace(tl, segments=[seg]), notes


def save_checkpoint(
    res: ReplayResult,
    directory: str | Path,
    *,
    base_vocab: Sequence[str] = (),
    base_codes: Sequence[int] = (),
    queued_labels: Sequence[str] = (),
    keep: int = 5,
) -> Path:
    """Write the replayed model as a daemon checkpoint in ``directory`` (the daemon's
    ``[checkpoint] dir``), so that ``roger daemon`` resumes from it.

    ``base_vocab``/``base_codes`` are the labels of the pairs the initial model had learned
    (a daemon checkpoint's ``label_vocab``/``label_codes``) and ``queued_labels`` those of its
    queued pairs given as ``initial_pairs``; pairs without a known label get the empty label.
    The checkpoint names the session and segment it stands at, so the daemon's start-up
    recovery only re-learns what was logged after the replayed pairs.
    """
    from roger_daemon.checkpoint import write_checkpoint

    if res.model is None:
        raise ReplayError("nothing was replayed: no model to save")
    if res.learn_errors:
        raise ReplayError("the learner rejected some pairs; their labels cannot be lined up")
    model = res.model
    n = int(model.n_learned)
    vocab = [str(v) for v in base_vocab]
    index = {v: i for i, v in enumerate(vocab)}

    def code(label: str) -> int:
        if label not in index:
            index[label] = len(vocab)
            vocab.append(label)
        return index[label]

    own = [code(lab) for lab in [*queued_labels, *res.labels]][-n:] if n else []
    earlier = n - len(own)  # pairs the initial model had learned
    base = [int(c) for c in base_codes][:earlier]
    codes = base + ([code("")] * (earlier - len(base)) if earlier > len(base) else []) + own
    seg_no = len(res.timeline.segments) - 1
    last = res.pairs[-1].tick if res.pairs else None
    d = res.timeline.dims
    assert d is not None
    state = dict(model.state_dict())
    daemon = {
        "label_vocab": np.array(vocab, dtype=np.str_) if vocab else np.zeros(0, dtype="<U1"),
        "label_codes": np.array(codes, dtype=np.int32),
        "queue_x": np.zeros((0, d.x)), "queue_y": np.zeros((0, d.y)),
        "queue_labels": np.zeros(0, dtype=np.int32), "queue_ticks": np.zeros(0, dtype=np.int64),
    }
    meta = {
        "reason": "replay", "updates": n, "x_dim": d.x, "y_dim": d.y,
        "model": res.model_kind, "seed": res.seed, "params": res.params,
        "counters": {"last_learned_tick": last, "last_tick": last or 0},
        "session_id": res.info.session_id, "session_segment": seg_no,
        "replayed_from": [str(p) for p in res.files],
    }
    path, _ = write_checkpoint(Path(directory), res.robot, state, daemon, meta, keep=keep)
    return path

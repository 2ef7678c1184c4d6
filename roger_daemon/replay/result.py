"""What a replay rebuilt and how it compares with the recording: per-prediction differences,
the decisions' margins, the verdict and the summary ``roger replay --json`` prints."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.protocol import Learner
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.timeline import LearnedPair, Timeline

__all__ = [
    "ROUND_OFF_MARGIN",
    "DecisionMargin",
    "DigestCheck",
    "Model",
    "ModelFactory",
    "PredictionDiff",
    "ReplayError",
    "ReplayResult",
]


class ReplayError(RuntimeError):
    """The session cannot be replayed as asked (e.g. it resumed from a checkpoint not given)."""


#: What replay rebuilds and drives: the learner contract (docs/learner-api.md), one owner.
Model = Learner


#: ``factory(model_kind, d_x, d_y, params_mapping_or_None, seed_or_None) -> Model``
ModelFactory = Callable[[str, int, int, "Mapping[str, Any] | None", "int | None"], Model]


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
class DigestCheck:
    """A checkpoint's model digest the daemon recorded, against the replayed model's."""

    segment: int
    updates: int
    match: bool


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
    digests: list[DigestCheck] = field(default_factory=list)  # recorded model digests checked

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
        """Every recorded prediction recomputed to the last bit (and none unreplayable), and
        every recorded model digest reproduced."""
        return (self.unreplayable == 0 and all(d.bit_identical for d in self.diffs)
                and all(c.match for c in self.digests))

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
            "decision_records": tl.decisions,
            "model_digests": {"checked": len(self.digests),
                              "matched": sum(c.match for c in self.digests)},
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

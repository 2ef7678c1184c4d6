"""Scores of the experiment: success intervals, segmentation against the HCC's labels.

Pure functions on arrays; no I/O. Paper section IV.A: experts are grouped by the subtask that
generated the majority of their data, and the segmentation is compared with the ground truth.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.stats import binomtest
from sklearn.metrics import adjusted_rand_score, normalized_mutual_info_score

from roger_daemon.labels import majority_labels

__all__ = [
    "SegmentationScores",
    "SuccessRate",
    "downsample_per_label",
    "majority_labels",
    "segmentation_scores",
    "success_rate",
]


@dataclass(frozen=True)
class SuccessRate:
    """Successes out of trials with a 95 % Wilson score interval."""

    successes: int
    trials: int
    rate: float
    ci_low: float
    ci_high: float

    def to_json(self) -> dict[str, float | int]:
        """The fields ``results.json`` carries for one controller."""
        return {
            "success_rate": self.rate,
            "successes": self.successes,
            "trials": self.trials,
            "ci95_low": self.ci_low,
            "ci95_high": self.ci_high,
        }


def success_rate(outcomes: Sequence[bool]) -> SuccessRate:
    """Rate of ``True`` in ``outcomes`` with its Wilson 95 % interval (scipy's binomtest)."""
    n = len(outcomes)
    k = int(sum(bool(o) for o in outcomes))
    if n == 0:
        return SuccessRate(0, 0, float("nan"), float("nan"), float("nan"))
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return SuccessRate(k, n, k / n, float(ci.low), float(ci.high))


def downsample_per_label(
    labels: Sequence[str], limit: int, rng: np.random.Generator
) -> npt.NDArray[np.int64]:
    """Indices keeping at most ``limit`` random points per label, in the original order.

    Paper section IV: "we first downsample (without changing the order) to 1000 random data
    points from each subtask".
    """
    if limit < 1:
        raise ValueError(f"limit must be an integer >= 1, got {limit}")
    labels_arr = np.asarray(labels)
    keep: list[npt.NDArray[np.int64]] = []
    for label in sorted(set(labels_arr.tolist())):
        idx = np.flatnonzero(labels_arr == label)
        if idx.size > limit:
            idx = rng.choice(idx, size=limit, replace=False)
        keep.append(idx.astype(np.int64))
    if not keep:
        return np.zeros(0, dtype=np.int64)
    return np.sort(np.concatenate(keep))


@dataclass(frozen=True)
class SegmentationScores:
    """The MAP particle's experts scored against the demonstrator's subtask labels."""

    experts: int
    purity: float
    ari: float
    nmi: float
    #: per subtask: the share of its points held by its largest expert, and by its 3 largest
    largest_share: dict[str, float]
    top3_share: dict[str, float]
    #: per subtask: how many experts have it as majority label
    experts_per_subtask: dict[str, int]


def segmentation_scores(
    assignments: Sequence[int], labels: Sequence[str]
) -> SegmentationScores:
    """Purity, adjusted Rand index, normalised mutual information and per-subtask shares."""
    a = np.asarray(assignments, dtype=np.int64)
    lab = np.asarray(labels)
    if a.shape != lab.shape:
        raise ValueError(f"assignments {a.shape} and labels {lab.shape} differ in shape")
    if a.size == 0:
        raise ValueError("no learned points to score")
    experts = np.unique(a)
    purity = sum(Counter(lab[a == e].tolist()).most_common(1)[0][1] for e in experts) / a.size
    largest: dict[str, float] = {}
    top3: dict[str, float] = {}
    for label in sorted(set(lab.tolist())):
        sizes = sorted(Counter(a[lab == label].tolist()).values(), reverse=True)
        total = sum(sizes)
        largest[label] = sizes[0] / total
        top3[label] = sum(sizes[:3]) / total
    per_subtask = Counter(majority_labels(a.tolist(), lab.tolist()).values())
    return SegmentationScores(
        experts=int(experts.size),
        purity=float(purity),
        ari=float(adjusted_rand_score(lab, a)),
        nmi=float(normalized_mutual_info_score(lab, a)),
        largest_share=largest,
        top3_share=top3,
        experts_per_subtask=dict(sorted(per_subtask.items())),
    )

"""How well a learned automaton's graph agrees with the HCC's (labels used for this score only).

The learned transitions' states are ROGER's experts; the hand-coded controller's are its
subtasks. To compare the two graphs each expert is mapped to the majority demonstrator label
of the points ROGER assigned to it (:func:`roger_daemon.labels.majority_labels`; the labels
touch nothing else), so every learned switch ``s -> j`` between experts of *different* labels
is a switch between subtasks ``L(s) -> L(j)``; a switch between two experts of one label is
the same subtask and not an edge. The HCC's graph is the set of subtask switches its
demonstrations made (consecutive ticks of one episode). Scores (docs/autonomy.md):

* ``precision``: share of the learned label edges that are HCC edges;
* ``recall``: share of the HCC's edges that the learned graph has;
* ``f1``: their harmonic mean (the headline ``graph_agreement``);
* ``weighted_precision``: share of the learned cross-label switch *counts* on HCC edges;
* ``same_label_switch_share``: share of all learned switches that stay within one label
  (the chatter between experts of one subtask).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["graph_agreement", "hcc_edges", "learned_label_edges", "mean_agreement"]


def hcc_edges(labels: Sequence[str], episode_start: Sequence[bool] | None = None
              ) -> Counter[tuple[str, str]]:
    """The HCC's subtask switches in its demonstrations (none across an episode start)."""
    out: Counter[tuple[str, str]] = Counter()
    for t in range(1, len(labels)):
        if episode_start is not None and episode_start[t]:
            continue
        if labels[t] != labels[t - 1]:
            out[(labels[t - 1], labels[t])] += 1
    return out


def learned_label_edges(fsm: Any, expert_labels: Mapping[int, str]
                        ) -> tuple[Counter[tuple[str, str]], int, int]:
    """``(label edges with counts, switches within one label, switches between experts with a
    label)`` of a learned FSM's transitions."""
    edges: Counter[tuple[str, str]] = Counter()
    same = total = 0
    t = fsm.transitions
    for (s, j), n in zip(t.pairs.tolist(), t.count.tolist(), strict=True):
        if s == j or s < 0 or s not in expert_labels or j not in expert_labels:
            continue
        total += int(n)
        a, b = expert_labels[s], expert_labels[j]
        if a == b:
            same += int(n)
        else:
            edges[(a, b)] += int(n)
    return edges, same, total


def graph_agreement(fsm: Any, expert_labels: Mapping[int, str], labels: Sequence[str],
                    episode_start: Sequence[bool] | None = None) -> dict[str, Any]:
    """The module docstring's scores of one learned FSM against the demonstrations' HCC graph."""
    truth = hcc_edges(labels, episode_start)
    learned, same, total = learned_label_edges(fsm, expert_labels)
    hit = set(learned) & set(truth)
    precision = len(hit) / len(learned) if learned else 0.0
    recall = len(hit) / len(truth) if truth else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    cross = sum(learned.values())
    return {
        "graph_agreement": round(f1, 3), "precision": round(precision, 3),
        "recall": round(recall, 3),
        "weighted_precision": round(sum(learned[e] for e in hit) / cross, 3) if cross else 0.0,
        "same_label_switch_share": round(same / total, 3) if total else 0.0,
        "edges_learned": len(learned), "edges_hcc": len(truth),
        "missing_hcc_edges": sorted(f"{a}->{b}" for a, b in set(truth) - set(learned)),
    }


def mean_agreement(rows: Sequence[Mapping[str, Any]]) -> float | None:
    """The mean ``graph_agreement`` over seeds (None without rows)."""
    vals = [float(r["graph_agreement"]) for r in rows if "graph_agreement" in r]
    return round(float(np.mean(vals)), 3) if vals else None

"""The HCC transitioner's choice among ROGER's experts (``roger hcc --role transitioner``).

The paper (section IV.A) groups the learned experts by the subtask that generated most of
their data and lets the hand-coded FSM pick the group of its current subtask; it leaves open
which of a group's experts acts. The rules here answer that, for the Zenoh node
(:mod:`simulator.controllers.hcc_node`) and the in-process evaluation
(:mod:`simulator.experiment.inprocess`) alike, so both act identically. docs/goal-scoring.md
compares them.
"""

from __future__ import annotations

import numpy as np

from protocols import ExpertOutput
from protocols.aibo import DIMS

__all__ = ["DEFAULT_RULE", "RULES", "choose_expert", "subtask_mixture", "transition_command"]


#: How the transitioner picks among the experts of the current subtask (``--rule``).
RULES = ("support", "variance", "gate", "mixture")

#: The default rule: the gate-weighted mean of the subtask's experts.  Chosen over three
#: demonstration streams x three learner seeds (docs/goal-scoring.md, "The transitioner's
#: rule"): 36 of 117 goals against 13 for ``support``.
DEFAULT_RULE = "mixture"


def choose_expert(
    multimap: tuple[ExpertOutput, ...], subtask: str, rule: str = DEFAULT_RULE
) -> tuple[ExpertOutput | None, str]:
    """The expert the transitioner uses for ``subtask``, and how it was chosen.

    Among the experts labelled ``subtask`` (majority label of their data, paper section IV.A):
    ``rule = "support"`` takes the expert holding the most points (the broadest fit of the
    subtask), ``"variance"`` the lowest predictive variance at this perception, ``"gate"``
    the highest gate probability (``"mixture"``, the default, too: its command, from
    :func:`transition_command`, is the gate-weighted mean of these experts); either way
    ``"label"``. If none carries the label, the highest-probability expert overall
    (``"fallback_top"``); ``(None, "fallback_mean")`` for an empty multimap. Remaining ties
    go to the higher gate probability, then the lower expert id.
    """
    if rule not in RULES:
        raise ValueError(f"transitioner rule must be one of {RULES}, got {rule!r}")
    if not multimap:
        return None, "fallback_mean"
    ranked = sorted(multimap, key=lambda e: (-e.p, e.expert))
    mine = [e for e in ranked if e.label == subtask]
    if not mine:
        return ranked[0], "fallback_top"
    if rule == "variance":
        return min(mine, key=lambda e: float(np.sum(e.var))), "label"
    if rule == "support":
        return max(mine, key=lambda e: e.n), "label"
    return mine[0], "label"


def subtask_mixture(
    multimap: tuple[ExpertOutput, ...], subtask: str
) -> tuple[np.ndarray, str, int] | None:
    """The gate-weighted mean of the experts labelled ``subtask`` (``--rule mixture``).

    Within one subtask the demonstrated policy is a unimap (docs/demonstrator.md), so the
    mixture-of-experts prediction restricted to that subtask's experts, ``sum_k p_k mean_k /
    sum_k p_k``, averages experts that agree in their overlap instead of the multimap's
    branches. ``(command, "label", expert with the largest weight)``, or ``None`` when no
    expert carries the label or their gate probabilities are all zero.
    """
    mine = [e for e in multimap if e.label == subtask]
    weights = np.array([e.p for e in mine], dtype=np.float64)
    total = float(weights.sum())
    if not mine or not total > 0.0:
        return None
    command = np.zeros(DIMS.y)
    for w, e in zip(weights / total, mine, strict=True):  # elementwise: no BLAS round-off
        command += w * np.asarray(e.mean, dtype=np.float64)
    top = mine[int(np.argmax(weights))]
    return command, "label", int(top.expert)


def transition_command(
    multimap: tuple[ExpertOutput, ...], mean: np.ndarray | None, subtask: str, rule: str
) -> tuple[np.ndarray, str, int]:
    """The transitioner's command for ``subtask``: (9-D command, how, expert id or -1).

    The chosen expert's mean (:func:`choose_expert`); with an empty multimap the prediction's
    own ``mean``. Shared by this node and the in-process evaluation
    (``simulator.experiment.inprocess``), so both act identically.
    """
    if rule == "mixture":
        mixed = subtask_mixture(multimap, subtask)
        if mixed is not None:
            return mixed
        rule = "support"  # no gate mass on the subtask's experts: its broadest expert
    expert, how = choose_expert(multimap, subtask, rule)
    if expert is None:
        y = np.zeros(DIMS.y) if mean is None else np.array(mean, dtype=np.float64)
        return y, how, -1
    return np.array(expert.mean, dtype=np.float64), how, int(expert.expert)

"""What ``roger replay --save-checkpoint`` can save instead of the replayed model: a model
made from it for a daemon in predict mode to serve.

* ``--merge-groups`` (:func:`merged`): ROGER's experts merged per group, one expert per
  majority label (:func:`roger_daemon.groups.merge_groups`; docs/goal-scoring.md, "merged
  groups"); each pair is labelled with its group.
* ``--split-gates`` (:func:`split`): each expert's gate split where its inputs form clusters,
  as a one-particle ROGER model (:func:`roger_daemon.gate_split_model.split_model`;
  docs/goal-scoring.md, "Split gates"). No label enters the split; the pairs keep theirs, and
  the daemon names each part's group by them as it names experts.

Both need the session from the model's first pair: they read every point the model learned.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from roger_daemon.config.settings import FSM_MODEL
from roger_daemon.labels import majority_labels
from roger_daemon.replay.session import ReplayError

__all__ = ["merged", "split"]


def _whole_session(res: Any, option: str) -> Any:
    """The replayed ROGER model, if it learned exactly the replayed pairs; else ReplayError."""
    model = res.model
    if model is None or res.model_kind not in ("roger", FSM_MODEL):
        raise ReplayError(f"{option} needs a ROGER model (model kind 'roger')")
    if int(model.n_learned) != len(res.pairs):
        raise ReplayError(
            f"{option} needs the session from the model's first pair: the model learned "
            f"{model.n_learned} pairs, the replayed log holds {len(res.pairs)} of them")
    return model


def merged(res: Any) -> Any:
    """``res`` with its model replaced by the model's experts merged per group and each pair
    labelled with its group."""
    from roger_daemon.groups import merge_groups

    model = _whole_session(res, "--merge-groups")
    out, groups = merge_groups(np.array([p.x for p in res.pairs]),
                               np.array([p.y for p in res.pairs]), res.labels, model,
                               params=model.params, seed=res.seed)
    return replace(res, model=out, labels=groups, params=out.params.to_mapping(),
                   expert_labels=majority_labels(np.asarray(out.assignments()).tolist(),
                                                 groups))


def split(res: Any) -> Any:
    """``res`` with its model replaced by its split gates as a one-particle ROGER model."""
    from roger_daemon.gate_split import SplitGates
    from roger_daemon.gate_split_model import split_model

    model = _whole_session(res, "--split-gates")
    out = split_model(SplitGates(model, np.array([p.x for p in res.pairs]),
                                 seed=int(res.seed or 0)))
    return replace(res, model=out, model_kind="roger", params=out.params.to_mapping(),
                   expert_labels=majority_labels(np.asarray(out.assignments()).tolist(),
                                                 list(res.labels)))

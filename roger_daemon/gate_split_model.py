"""Split gates as an ordinary ROGER model, for the daemon, checkpoints and replay.

:class:`~roger_daemon.gate_split.SplitGates` answers with one multimap row per part of a
split gate: the part's own NIW gate, its expert's GP.  :func:`split_model` writes exactly
that as a one-particle :class:`~roger_daemon.learner.Roger`: one expert per part, whose gate
is the part's and whose SOGP is a copy of the part's expert's, the particle's assignment of
every learned point its part.  Its predictions are the split gates' float for float (gate
probabilities ``p(part | x) ∝ n_part t_part(x)`` through the model's own rule, with its
``min_support``; the GPs the same arrays), so whatever serves a ROGER model serves split
gates: ``roger daemon`` from a checkpoint (``roger replay --split-gates --save-checkpoint``),
the experiment's Zenoh path (docs/goal-scoring.md, "Split gates").  Labels take no part.

It is a state dict built from the trained model's (layout: :mod:`roger_daemon.learner.state`),
checked by loading it: the result continues as a one-particle ROGER model would if it is
taught more (each part's SOGP then learns on its own).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from roger_daemon.gate_split import SplitGates
from roger_daemon.learner import Roger
from roger_daemon.learner.state import pack_experts, pack_meta, unpack_experts, unpack_meta

__all__ = ["split_model"]


def split_model(split: SplitGates) -> Roger:
    """The one-particle ROGER model whose experts are ``split``'s parts (module docstring)."""
    model: Any = split.model
    terms = split.terms
    state = model.state_dict()
    meta = unpack_meta(state, Roger.kind)
    # the MAP particle's version of each expert (particles may hold other versions of an id)
    best = int(np.asarray(state["particle_log_weights"]).argmax())
    offsets = np.asarray(state["particle_offsets"])
    held = np.asarray(state["particle_experts"])[offsets[best]:offsets[best + 1]].tolist()
    every = unpack_experts(state, terms.new_expert)
    ids = np.asarray(state["expert_id"])
    gps = {int(ids[c]): every[c] for c in held}
    parts = split.parts
    n = len(parts)
    out: dict[str, np.ndarray] = pack_experts([gps[q.expert] for q in parts], terms.d_model,
                                              terms.d_y)
    out.update({f"gate_{name}": np.array(getattr(split.gates, name)[:n])
                for name in split.gates.FIELDS})
    out["expert_id"] = np.arange(n, dtype=np.int64)
    out["expert_count"] = np.array([q.n for q in parts], dtype=np.int64)
    out["particle_log_weights"] = np.zeros(1)
    out["particle_offsets"] = np.array([0, n], dtype=np.int64)
    out["particle_experts"] = np.arange(n, dtype=np.int64)
    # one lineage: every point but the last settled, the last in the window (history.py)
    point_part = split.assignments()
    out["history_settled"] = point_part[:-1].copy()
    out["history_exception_points"] = np.zeros(0, dtype=np.int64)
    out["history_exception_ids"] = np.zeros((0, 1), dtype=np.int64)
    out["history_ancestor"] = np.zeros((1, 1), dtype=np.int32)
    out["history_expert"] = point_part[-1:].reshape(1, 1).copy()
    meta["params"] = {**meta["params"], "particles": 1}
    meta["next_expert_id"] = n
    out["meta"] = pack_meta(meta)
    return Roger.from_state_dict(out)

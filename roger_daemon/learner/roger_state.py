"""A :class:`~.roger.Roger` model as flat named arrays and back (layout: :mod:`.state`).

Split from :mod:`.roger` (persistence, not inference): :func:`roger_state_dict` is
``Roger.state_dict`` and :func:`load_roger_state` fills a freshly constructed model, so that it
continues exactly as the saved one would.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from roger_daemon.learner.history import SegmentationHistory
from roger_daemon.learner.state import (
    SCHEMA_VERSION,
    generator_from_state,
    generator_state,
    pack_experts,
    pack_meta,
    unpack_experts,
)

if TYPE_CHECKING:
    from roger_daemon.learner.roger import Roger

__all__ = ["load_roger_state", "roger_state_dict"]


def roger_state_dict(model: Roger) -> dict[str, np.ndarray]:
    """Flat named arrays plus JSON metadata; see :mod:`.state`.  No object arrays."""
    # canonical order: slots by first appearance in the particles (not by slot number)
    flat = model._slots
    _, first = np.unique(flat, return_index=True)
    live = flat[np.sort(first)]
    compact = np.full(len(model._gps), -1, dtype=np.int64)
    compact[live] = np.arange(live.size)
    gps = [model._gps[s] for s in live.tolist()]
    assert all(g is not None for g in gps)
    out = pack_experts([g for g in gps if g is not None], model._dm, model.d_y)
    g = model._gates
    for name in g.FIELDS:
        out[f"gate_{name}"] = getattr(g, name)[live].copy()
    out["expert_id"] = model._ids[live].copy()
    out["expert_count"] = model._npts[live].copy()
    out["particle_log_weights"] = model._logw.copy()
    out["particle_offsets"] = model._starts.copy()
    out["particle_experts"] = compact[flat]
    out.update(model._history.state())
    out["meta"] = pack_meta({
        "schema": SCHEMA_VERSION,
        "kind": model.kind,
        "d_x": model.d_x,
        "d_y": model.d_y,
        "params": model.params.to_mapping(),
        "n_learned": model.n_learned,
        "next_expert_id": model._next_id,
        "rng_learn": generator_state(model._learn_rng),
        "rng_predict": generator_state(model._predict_rng),
    })
    return out


def load_roger_state(model: Roger, state: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """Set ``model`` (freshly built from the same params) to the saved ``state``."""
    model._learn_rng = generator_from_state(meta["rng_learn"])
    model._predict_rng = generator_from_state(meta["rng_predict"])
    gps = unpack_experts(state, model._new_gp)
    u = len(gps)
    for _ in range(u):
        model._alloc_slot()
    for s, gp in enumerate(gps):
        model._gps[s] = gp
    g = model._gates
    for name in g.FIELDS:
        getattr(g, name)[:u] = state[f"gate_{name}"]
    model._ids[:u] = state["expert_id"]
    model._npts[:u] = state["expert_count"]
    offsets = np.asarray(state["particle_offsets"], dtype=np.int64)
    flat = np.asarray(state["particle_experts"], dtype=np.int64)
    model._slots, model._starts = flat.copy(), offsets.copy()
    model._logw = np.asarray(state["particle_log_weights"], dtype=np.float64).copy()
    model._ref = np.bincount(flat, minlength=len(model._gps)).astype(np.int64)
    model.n_learned = int(meta["n_learned"])
    model._next_id = int(meta["next_expert_id"])
    model._history = SegmentationHistory.from_state(
        model.params.particles, state.get("history_settled"),  # absent before schema 3
        state["history_ancestor"], state["history_expert"],
        state.get("history_exception_points"), state.get("history_exception_ids"))  # schema >= 4

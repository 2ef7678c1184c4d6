"""A ROGER model's experts and history as flat named arrays and back (layout: :mod:`.state`).

Persistence, not inference: :func:`roger_arrays` is the array part of ``Roger.state_dict``
(the metadata is the model's), :func:`load_roger_arrays` fills a freshly built model's store
and returns its history, so that it continues exactly as the saved one would.
"""

from __future__ import annotations

import numpy as np

from roger_daemon.learner.history import SegmentationHistory
from roger_daemon.learner.roger_terms import Experts, ModelTerms
from roger_daemon.learner.state import pack_experts, unpack_experts

__all__ = ["load_roger_arrays", "roger_arrays"]


def roger_arrays(store: Experts, history: SegmentationHistory, terms: ModelTerms
                 ) -> dict[str, np.ndarray]:
    """The distinct experts (in the store's canonical order, :meth:`.ExpertStore.canonical`),
    the store's gates, ids, counts and particles, and the history: no object arrays."""
    live, _ = store.canonical()
    out = pack_experts(store.experts(live.tolist()), terms.d_model, terms.d_y)
    out.update(store.state())
    out.update(history.state())
    return out


def load_roger_arrays(store: Experts, terms: ModelTerms, state: dict[str, np.ndarray],
                      next_id: int) -> SegmentationHistory:
    """Fill the fresh ``store`` from ``state`` (:func:`roger_arrays`); the saved history."""
    store.load(unpack_experts(state, terms.new_expert), state, next_id)
    return SegmentationHistory.from_state(
        terms.params.particles, state.get("history_settled"),  # absent before schema 3
        state["history_ancestor"], state["history_expert"],
        state.get("history_exception_points"), state.get("history_exception_ids"))  # >= 4

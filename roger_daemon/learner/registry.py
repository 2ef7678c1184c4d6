"""The learners the project ships, by kind: build one, or rebuild one from its state dict.

One registry (:data:`MODELS`) for every place that picks a learner by name: the daemon's
``[[robots]] model`` (its config parser's choices, its fresh and reset models), learner
workers, replay (the model a session log names), the checkpoint's ``learner.kind``, and the
conformance suite (``tests/learner/test_conformance.py`` runs over every model here). A new
learner is added to :data:`MODELS` and must pass that suite unchanged (docs/learner-api.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.roger import Roger
from roger_daemon.learner.state import unpack_meta
from roger_daemon.learner.unimap import UnimapGP

__all__ = ["MODELS", "build_model", "load_model"]

#: kind -> class: the paper's ROGER and the single-GP baseline (section V's "unimap").
MODELS: dict[str, type[Roger] | type[UnimapGP]] = {Roger.kind: Roger, UnimapGP.kind: UnimapGP}


def build_model(kind: str, d_x: int, d_y: int,
                params: RogerParams | Mapping[str, Any] | None = None,
                seed: int | None = None) -> Roger | UnimapGP:
    """A fresh model of ``kind`` (a key of :data:`MODELS`); ``params`` a
    :class:`RogerParams` or its mapping (``RogerParams.to_mapping``), ``None`` for the
    defaults. An unknown kind raises ``ValueError`` naming the known ones."""
    cls = MODELS.get(kind)
    if cls is None:
        raise ValueError(f"unknown model kind {kind!r} (one of {', '.join(sorted(MODELS))})")
    if params is not None and not isinstance(params, RogerParams):
        params = RogerParams.from_mapping(dict(params))
    return cls(d_x=d_x, d_y=d_y, params=params, seed=seed)


def load_model(state: Mapping[str, np.ndarray]) -> Roger | UnimapGP:
    """The model a state dict holds, by its ``meta["kind"]`` (``from_state_dict`` of that
    class).  Accepts the mapping returned by ``np.load``."""
    arrays = {k: np.asarray(state[k]) for k in state}
    kind = unpack_meta(arrays).get("kind")
    cls = MODELS.get(str(kind))
    if cls is None:
        raise ValueError(f"state dict holds an unknown model kind {kind!r}")
    return cls.from_state_dict(arrays)

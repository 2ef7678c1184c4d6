"""The learners the project ships, by kind, and rebuilding one from its state dict.

:data:`MODELS` is the table every place that picks a model by name starts from: the daemon's
registry (:mod:`roger_daemon.config.models`, which adds ROGER with learned transitions and builds a
model by kind for the config, the daemon, its workers and replay) and the conformance suite
(``tests/learner/test_conformance.py`` runs over every model here). A new learner is added to
:data:`MODELS` and must pass that suite unchanged (docs/learner-api.md).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from roger_daemon.learner.roger import Roger
from roger_daemon.learner.state import unpack_meta
from roger_daemon.learner.unimap import UnimapGP

__all__ = ["MODELS", "load_model"]

#: kind -> class: the paper's ROGER and the single-GP baseline (section V's "unimap").
MODELS: dict[str, type[Roger] | type[UnimapGP]] = {Roger.kind: Roger, UnimapGP.kind: UnimapGP}


def load_model(state: Mapping[str, np.ndarray]) -> Roger | UnimapGP:
    """The model a state dict holds, by its ``meta["kind"]`` (``from_state_dict`` of that
    class).  Accepts the mapping returned by ``np.load``."""
    arrays = {k: np.asarray(state[k]) for k in state}
    kind = unpack_meta(arrays).get("kind")
    cls = MODELS.get(str(kind))
    if cls is None:
        raise ValueError(f"state dict holds an unknown model kind {kind!r}")
    return cls.from_state_dict(arrays)

"""``load_model``: rebuild whichever learner a state dict holds."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from roger_daemon.learner.roger import Roger
from roger_daemon.learner.state import unpack_meta
from roger_daemon.learner.unimap import UnimapGP

__all__ = ["load_model"]


def load_model(state: Mapping[str, np.ndarray]) -> Roger | UnimapGP:
    """Dispatch on ``meta["kind"]`` to :meth:`Roger.from_state_dict` or
    :meth:`UnimapGP.from_state_dict`.  Accepts the mapping returned by ``np.load``."""
    arrays = {k: np.asarray(state[k]) for k in state}
    kind = unpack_meta(arrays).get("kind")
    if kind == Roger.kind:
        return Roger.from_state_dict(arrays)
    if kind == UnimapGP.kind:
        return UnimapGP.from_state_dict(arrays)
    raise ValueError(f"state dict holds an unknown model kind {kind!r}")

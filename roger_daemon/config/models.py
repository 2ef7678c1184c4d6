"""The model kinds a config names (``[[robots]] model``): build one by kind, load one back.

One registry (:data:`MODELS`) for every place that picks a model by name: the config parser's
choices, the daemon's fresh and reset models (``roger_daemon.daemon.resume.make_model``),
learner workers, replay (the model a session log names, ``roger replay --model``) and the
checkpoints it loads. It is the learner's own registry
(:data:`roger_daemon.learner.registry.MODELS`: the paper's ROGER and the unimap baseline) plus
ROGER with its transitions learned online (:class:`roger_daemon.fsm.online.RogerFSM`, kind
:data:`~roger_daemon.config.settings.FSM_MODEL`), which the learner cannot name (it imports
nothing else of ``roger_daemon``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from roger_daemon.config.settings import FSM_MODEL
from roger_daemon.fsm.online import RogerFSM, has_fsm
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.registry import MODELS as LEARNER_MODELS
from roger_daemon.learner.registry import load_model as load_learner

__all__ = ["MODELS", "build_model", "load_model"]

#: kind -> class of every model the daemon serves.
MODELS: dict[str, type[Any]] = {**LEARNER_MODELS, FSM_MODEL: RogerFSM}


def build_model(kind: str, d_x: int, d_y: int,
                params: RogerParams | Mapping[str, Any] | None = None,
                seed: int | None = None) -> Any:
    """A fresh model of ``kind`` (a key of :data:`MODELS`); ``params`` a
    :class:`~roger_daemon.learner.RogerParams` or its mapping (``to_mapping``), ``None`` for
    the defaults. An unknown kind raises ``ValueError`` naming the known ones."""
    cls = MODELS.get(kind)
    if cls is None:
        raise ValueError(f"unknown model kind {kind!r} (one of {', '.join(MODELS)})")
    if params is not None and not isinstance(params, RogerParams):
        params = RogerParams.from_mapping(dict(params))
    return cls(d_x, d_y, params, seed)


def load_model(state: Mapping[str, np.ndarray]) -> Any:
    """The model a state dict holds: a :class:`~roger_daemon.fsm.online.RogerFSM` when it
    carries learned transitions (``fsm.*``), else the learner's kind it names
    (:func:`roger_daemon.learner.load_model`). Accepts the mapping ``np.load`` returns."""
    if has_fsm(state):
        return RogerFSM.from_state_dict({k: np.asarray(state[k]) for k in state})
    return load_learner({k: state[k] for k in state})

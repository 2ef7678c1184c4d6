"""ROGER with its transitions learned online: the daemon's model kind ``"roger+fsm"``.

:class:`RogerFSM` is a :class:`~roger_daemon.learner.Roger` model (the same experts, bit for
bit: its ``learn_one`` is Roger's, then one more step) that also teaches a
:class:`~roger_daemon.fsm.controller.LearnedFSM` every pair it learns, as the pair arrives
(docs/autonomy.md, *Learned in the daemon*):

* the pair's state is the expert the MAP particle gave it in that very step (the newest entry
  of the MAP particle's assignment sequence, ``assignments_at([n - 1])``; O(1) and no
  prediction). Later revisions of the few unsettled points are not taught again;
* the memories advance on the pair's perception and on the demonstrated command, as in
  :func:`~roger_daemon.fsm.fit.fit_fsm`; the pairs are one continuous stream (a learned pair
  carries no episode boundary in the daemon's logs, so none is used: an episode's start is
  learned as an ordinary switch, and the acting side starts each episode on the gate argmax).

Updating at once rather than refitting every N pairs: one rank-1 update of one pair's NIW
statistics costs O(D^2) for D = 26 features, far under a learner step (``roger bench learner``
measures both); a refit would replay the whole stream and grow with it.

The state dict is Roger's arrays unchanged plus ``fsm.*`` (:meth:`LearnedFSM.state_dict`), so
the experts' part (:meth:`RogerFSM.experts_state`) has the digest a plain Roger model would
have; :func:`roger_daemon.config.models.load_model` loads either kind (a state without
``fsm.*`` is a plain model, as in every checkpoint written before this kind existed). No label
is read anywhere here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.config.settings import FSM_MODEL
from roger_daemon.fsm.controller import LearnedFSM
from roger_daemon.fsm.memory import MemorySpec
from roger_daemon.learner.model_args import Seed
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.roger import Roger

__all__ = ["FSM_PREFIX", "MODEL_KIND", "RogerFSM", "default_memory", "has_fsm",
           "newest_assignment"]

#: The daemon's model kind of a ROGER model with learned transitions (``[[robots]] model``).
MODEL_KIND = FSM_MODEL

#: Prefix of the learned transitions' arrays in the model's state dict.
FSM_PREFIX = "fsm."


def default_memory(d_x: int, d_y: int) -> MemorySpec:
    """The memory layout of a ``d_x``/``d_y`` robot: the AIBO's (the one shipped); raises
    ``ValueError`` for other dimensions."""
    from protocols.aibo import DIMS

    if (d_x, d_y) != (DIMS.x, DIMS.y):
        raise ValueError(f"learned transitions need a memory layout; only the AIBO's "
                         f"({DIMS.x}/{DIMS.y}) is shipped, not {d_x}/{d_y}")
    from roger_daemon.fsm.profiles import aibo_memory

    return aibo_memory()


class RogerFSM(Roger):
    """A ROGER model whose every learned pair also teaches its transitions (module
    docstring). Same constructor as :class:`Roger`, plus the memory layout ``spec``
    (default: :func:`default_memory`)."""

    model_kind = MODEL_KIND

    def __init__(self, d_x: int, d_y: int, params: RogerParams | None = None,
                 seed: Seed = None, spec: MemorySpec | None = None) -> None:
        super().__init__(d_x, d_y, params, seed)
        from roger_daemon.fsm.jit_fsm import warm

        warm()  # the transitions' kernels loaded (numba's cache: roger compile) before a pair
        spec = default_memory(self.d_x, self.d_y) if spec is None else spec
        spec.check_dims(self.d_x, self.d_y)
        self.fsm = LearnedFSM(spec)

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """Roger's Algorithm 1, then the pair teaches the transitions (its MAP expert)."""
        super().learn_one(x, y)
        self.learn_transition(x, y)

    def learn_transition(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """The transitions' part of :meth:`learn_one`, for the pair just learned."""
        state = newest_assignment(self)
        self.fsm.observe(x, y, state, learn_start=False)

    def experts_state(self) -> dict[str, np.ndarray]:
        """Roger's own state dict: the experts, the particles, the history (no ``fsm.*``)."""
        return super().state_dict()

    def state_dict(self) -> dict[str, np.ndarray]:
        """Roger's arrays and the transitions' under ``fsm.``."""
        out = self.experts_state()
        out.update({FSM_PREFIX + k: v for k, v in self.fsm.state_dict().items()})
        return out

    @classmethod
    def from_state_dict(cls, state: Mapping[str, np.ndarray]) -> RogerFSM:
        """Rebuild from :meth:`state_dict`; a plain Roger state gets new, empty transitions."""
        from roger_daemon.learner.state import unpack_meta

        experts = {k: np.asarray(v) for k, v in state.items() if not k.startswith(FSM_PREFIX)}
        meta = unpack_meta(experts, Roger.kind)
        fsm = None
        if has_fsm(state):
            fsm = LearnedFSM.from_state_dict({k[len(FSM_PREFIX):]: np.asarray(v)
                                              for k, v in state.items()
                                              if k.startswith(FSM_PREFIX)})
        model = cls(int(meta["d_x"]), int(meta["d_y"]), RogerParams.from_mapping(meta["params"]),
                    spec=None if fsm is None else fsm.spec)
        model._load(experts, meta)
        if fsm is not None:
            model.fsm = fsm
        return model


def newest_assignment(model: Roger) -> int:
    """The MAP particle's expert of the pair ``model`` learned last: the id it chose in that
    step (``assignments()[-1]``, in O(1))."""
    return int(model.history.last_ids()[model.store.map_particle()])


def has_fsm(state: Mapping[str, Any]) -> bool:
    """Whether a model state dict (or a checkpoint's model arrays) holds learned transitions."""
    return f"{FSM_PREFIX}meta" in state

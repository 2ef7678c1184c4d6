"""The acting side of learned transitions, from the daemon's predictions (``roger play``).

:class:`Player` holds a :class:`~roger_daemon.fsm.controller.LearnedFSM` loaded from a daemon
checkpoint of a ``roger+fsm`` model (:func:`load_player`) and, for each perception, turns the
daemon's prediction of it (its multimap: every expert's id, gate probability, mean and size)
into the command of the expert the learned transitions choose. It never reads a label (the
multimap's ``label`` field is ignored) and imports nothing of the hand-coded controller
(docs/autonomy.md; ``tests/test_play_node.py`` checks both).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.fsm.controller import LearnedFSM
from roger_daemon.fsm.online import FSM_PREFIX, MODEL_KIND, has_fsm

__all__ = ["MultimapRows", "Player", "load_fsm_state", "load_player"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MultimapRows:
    """A prediction's multimap in the layout :meth:`LearnedFSM.choose` reads (the learner's
    ``MultimapTable`` fields it uses), built from ``Prediction.multimap``."""

    expert_ids: list[int]
    gate_probs: list[float]
    n_points: list[int]
    means: FloatArray = field(repr=False)

    @classmethod
    def of(cls, multimap: Sequence[Any], d_y: int) -> MultimapRows:
        """From ``ExpertOutput`` rows (``expert``, ``p``, ``mean``, ``n``); labels unread."""
        means = (np.array([np.asarray(e.mean, dtype=np.float64) for e in multimap])
                 if multimap else np.zeros((0, d_y)))
        return cls([int(e.expert) for e in multimap], [float(e.p) for e in multimap],
                   [int(e.n) for e in multimap], means)


class Player:
    """One robot's learned state and commands (module docstring)."""

    def __init__(self, fsm: LearnedFSM) -> None:
        self.fsm = fsm
        self.counts: dict[str, int] = {"learned": 0, "empty_multimap": 0}

    def reset(self) -> None:
        """A new episode: back to the start state."""
        self.fsm.reset()

    @property
    def state(self) -> int:
        """The current learned state (an expert id; -1 before the first tick)."""
        return self.fsm.state

    def command(self, x: npt.ArrayLike, multimap: Sequence[Any], fallback: npt.ArrayLike
                ) -> tuple[FloatArray, str]:
        """The command for perception ``x`` given its prediction's ``multimap``, and how it was
        chosen (``learned``, or ``empty_multimap``: the prediction's own mean ``fallback``)."""
        fb = np.asarray(fallback, dtype=np.float64)
        if not multimap:
            self.counts["empty_multimap"] += 1
            self.fsm.commit(fb)
            return fb.copy(), "empty_multimap"
        y = self.fsm.act(x, MultimapRows.of(multimap, fb.shape[0]))
        self.counts["learned"] += 1
        return y, "learned"

    def commit(self, command: npt.ArrayLike) -> None:
        """A command executed that :meth:`command` did not choose (a hold without prediction)."""
        self.fsm.commit(command)


def load_fsm_state(path: str | Path, robot: str = "aibo") -> dict[str, np.ndarray]:
    """The ``fsm.*`` arrays (prefix removed) of a daemon checkpoint file, the newest valid one
    of ``robot`` in a checkpoint directory, or a plain ``state_dict`` ``.npz``. Raises
    ``ValueError`` saying why none can be used."""
    from roger_daemon.daemon.checkpoint import CheckpointError, load_newest, read_checkpoint

    p = Path(path)
    model: dict[str, np.ndarray]
    if p.is_dir():
        ck = load_newest(p, robot)
        if ck is None:
            raise ValueError(f"no valid checkpoint of robot {robot!r} in {p}")
        model = ck.model
    else:
        try:
            model = read_checkpoint(p).model
        except CheckpointError:
            try:
                with np.load(p, allow_pickle=False) as z:
                    model = {k: z[k] for k in z.files}
            except (OSError, ValueError) as exc:
                raise ValueError(f"{p} is neither a daemon checkpoint nor a state .npz "
                                 f"({exc})") from None
    if not has_fsm(model):
        raise ValueError(
            f"{p} holds no learned transitions (a plain model): demonstrate with "
            f"[[robots]] model = \"{MODEL_KIND}\", or give a recorded session its transitions "
            f"with `roger replay LOG --model {MODEL_KIND} --save-checkpoint DIR` "
            "(docs/autonomy.md)")
    return {k[len(FSM_PREFIX):]: v for k, v in model.items() if k.startswith(FSM_PREFIX)}


def load_player(path: str | Path, robot: str = "aibo") -> Player:
    """A :class:`Player` of the transitions in ``path`` (:func:`load_fsm_state`)."""
    return Player(LearnedFSM.from_state_dict(load_fsm_state(path, robot)))

"""Teach a :class:`~roger_daemon.fsm.controller.LearnedFSM` a recorded demonstration.

For a model that learned (part of) a demonstration, :func:`fit_fsm` replays the whole
stream, tick by tick in order: each tick's state is the model's expert most responsible for
the demonstrated action (:func:`~roger_daemon.fsm.controller.responsible_expert`, from the
multimap at that perception), and the FSM observes it. The experiment uses it after
training (ROGER learns a downsampled stream, the transitions need every consecutive tick);
``roger model fsm fit`` uses it on a session log. No label is read.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.fsm.controller import LearnedFSM, responsible_expert
from roger_daemon.fsm.memory import MemorySpec

__all__ = ["fit_fsm"]


def fit_fsm(model: Any, x: npt.ArrayLike, y: npt.ArrayLike, episode_start: npt.ArrayLike,
            spec: MemorySpec, progress: Callable[[int], None] | None = None,
            learn: npt.ArrayLike | None = None,
            executed: npt.ArrayLike | None = None) -> LearnedFSM:
    """A :class:`LearnedFSM` over ``model``'s experts from the stream ``(x[t], y[t])``;
    ``episode_start[t]`` marks each episode's first tick. ``model`` is a ROGER model (its
    ``predict_table``); it is not changed. ``learn[t]`` false (default: all true): tick ``t``
    was executed but not demonstrated (the robot drove, ``roger teach``'s correct mode): it
    advances the memories with its command and teaches no transition. ``executed[t]``
    (default ``y[t]``): the command the robot executed, where it differs from the
    demonstrated one (perturbed demonstrations, ``--demo-noise``): the memories' odometry
    follows it, as the robot's own does when it acts; ``y`` still decides the state."""
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    ea = ya if executed is None else np.asarray(executed, dtype=np.float64)
    starts = np.asarray(episode_start, dtype=bool)
    taught = np.ones(len(starts), dtype=bool) if learn is None else np.asarray(learn, dtype=bool)
    if (xa.ndim != 2 or ya.ndim != 2 or ea.shape != ya.shape
            or not len(xa) == len(ya) == len(starts) == len(taught)):
        raise ValueError(f"fit_fsm: x (n, d_x), y and executed (n, d_y), n episode starts and "
                         f"n learn flags expected, got {xa.shape}, {ya.shape}, {ea.shape}, "
                         f"{starts.shape}, {taught.shape}")
    spec.check_dims(xa.shape[1], ya.shape[1])
    fsm = LearnedFSM(spec)
    for t in range(len(xa)):
        if not taught[t]:
            fsm.observe(xa[t], ea[t], -1, bool(starts[t]))
            continue
        _, table = model.predict_table(xa[t])
        fsm.observe(xa[t], ea[t], responsible_expert(table, ya[t]), bool(starts[t]))
        if progress is not None and t % 1000 == 999:
            progress(1000)
    return fsm

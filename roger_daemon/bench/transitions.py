"""The learned transitions' cost beside the learner's step (``roger bench learner``).

A ``roger+fsm`` model (roger_daemon/fsm/online.py) adds to every learned pair one transition
update: the MAP particle's expert of the pair and one
:meth:`~roger_daemon.fsm.controller.LearnedFSM.observe` (memories, features, a rank-1 NIW
update); ``roger play`` adds to every tick one :meth:`~roger_daemon.fsm.controller.LearnedFSM
.choose` on the prediction's multimap (memories, features, the Student-t scores of the current
state's successors). :class:`TransitionTimer` times both on the benchmark's own model and
stream, outside the step's timing, so the step's figures are unchanged (the choices after the
stream is learned, on its prediction queries: the transitions fixed, as ``roger play`` has
them); the target is at most
10 % of the mean step each (docs/autonomy.md, *Cost*).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

__all__ = ["TransitionTimer"]


class TransitionTimer:
    """Times the transitions' update after each step and their choice at each timed tick."""

    def __init__(self) -> None:
        from roger_daemon.fsm import LearnedFSM, aibo_memory
        from roger_daemon.fsm.online import newest_assignment

        self._newest = newest_assignment

        from roger_daemon.fsm.jit_fsm import warm

        warm()  # the kernels loaded from numba's cache before timing, as the learner's
        self.fsm = LearnedFSM(aibo_memory())
        self.update_ns: list[int] = []
        self.tick_ns: list[int] = []
        self.queries: list[np.ndarray] = []

    def after_update(self, model: Any, x: np.ndarray, y: np.ndarray) -> None:
        """The update a ``roger+fsm`` model makes after learning ``(x, y)`` (timed)."""
        t0 = time.perf_counter_ns()
        state = self._newest(model)
        self.fsm.observe(x, y, state, learn_start=False)
        self.update_ns.append(time.perf_counter_ns() - t0)

    def at_tick(self, x: np.ndarray) -> None:
        """A perception ``roger play`` will answer (:meth:`play`)."""
        self.queries.append(np.array(x, dtype=np.float64))

    def play(self, model: Any) -> None:
        """The choices ``roger play`` makes for the queries, with the transitions as learned
        (fixed, as while the daemon serves them in predict mode); each timed, the prediction
        that precedes it not."""
        self.fsm.reset()
        for x in self.queries:
            _, table = model.predict_table(x)
            t0 = time.perf_counter_ns()
            self.fsm.act(x, table)
            self.tick_ns.append(time.perf_counter_ns() - t0)

    def result(self, step_ns: list[int]) -> dict[str, Any]:
        """The costs in ms (p50, p99, mean) and as shares of the mean learner step."""
        step = float(np.mean(step_ns)) if step_ns else float("nan")
        out: dict[str, Any] = {"step_mean_ms": round(step / 1e6, 4)}
        for name, v in (("update", self.update_ns), ("tick", self.tick_ns)):
            a = np.asarray(v, dtype=np.float64)
            if not a.size:
                continue
            out[f"{name}_p50_ms"] = round(float(np.percentile(a, 50)) / 1e6, 4)
            out[f"{name}_p99_ms"] = round(float(np.percentile(a, 99)) / 1e6, 4)
            out[f"{name}_mean_ms"] = round(float(a.mean()) / 1e6, 4)
            out[f"{name}_share_of_step"] = round(float(a.mean()) / step, 4)
        out["pairs"] = len(self.fsm.transitions.count)
        return out

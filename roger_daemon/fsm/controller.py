"""The learned finite-state controller: ROGER's experts as states, learned transitions.

The paper's prediction (Algorithm 2) picks an expert by its gate alone and says that, on a
robot, "the stochastic selection of the expert will be replaced by the selection dictated by
the transition matrix" (section III.B); its section V names learning that matrix as future
work. :class:`LearnedFSM` does it, without a hand-coded line at run time and without the
demonstrator's labels (docs/autonomy.md):

* **learning** (:meth:`LearnedFSM.observe`): a demonstration stream of perceptions ``x``,
  executed actions ``y`` and each tick's expert (the state; :func:`responsible_expert` or the
  daemon's MAP assignment), the memories of :mod:`.memory` advanced by the demonstrator's own
  commands; each tick teaches the :class:`~.transitions.TransitionModel` one pair;
* **acting** (:meth:`LearnedFSM.choose`): at each tick the next state is the expert of the
  model's multimap maximising ``log N_sj + log t_sj(phi) + log g_j(x)``: the learned
  transition from the current state ``s`` and the expert's own NIW gate density ``g_j`` (its
  gate probability over its count, paper eq. for p(k | x)); its mean is the command
  (:meth:`act`). A state never seen to lead anywhere restarts from the episode-start row;
  a multimap with none of the successors falls back to the paper's gate argmax.

Two memories: one follows the demonstration (learning), one the robot's own commands
(acting), so a daemon may learn and act at once.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:  # jit_fsm imports numba: loaded only where a kernel is called (a daemon
    # with learner workers keeps numba out of its loop's process, docs/fleet.md)
    from roger_daemon.fsm.jit_fsm import AdvanceArgs
from roger_daemon.fsm.memory import Memory, MemorySpec, spec_from_mapping, spec_to_mapping
from roger_daemon.fsm.transitions import TransitionModel

__all__ = ["START", "LearnedFSM", "responsible_expert"]

FloatArray = npt.NDArray[np.float64]

#: The source state of an episode's first tick.
START = -1

#: Smallest gate probability taken into a score (a log of 0 would exclude an expert outright).
GATE_FLOOR = 1e-300

#: The command of a tick without one (the kernels read none).
_NO_COMMAND = np.zeros(1)

#: Version of :meth:`LearnedFSM.state_dict`'s layout.
SCHEMA = 1


def responsible_expert(table: Any, y: npt.ArrayLike) -> int:
    """The expert of a multimap table most responsible for the executed action ``y`` at the
    table's input: ``argmax_k log p(k | x) + log N(y; mean_k, var_k)`` (the MAP particle's
    share of ROGER's putative weight, docs/learner-math.md §4, without the new expert).
    ``-1`` for an empty table."""
    if not table.expert_ids:
        return -1
    yv = np.asarray(y, dtype=np.float64)
    var = np.asarray(table.variances, dtype=np.float64)
    with np.errstate(divide="ignore"):
        lg = np.log(np.asarray(table.gate_probs, dtype=np.float64))
    ll = lg - 0.5 * np.sum(np.log(2.0 * math.pi * var) + (yv - table.means) ** 2 / var, axis=1)
    return int(table.expert_ids[int(np.argmax(ll))])


class _Track:
    """One stream's running state: memory, current state, ticks in it, last command."""

    def __init__(self, spec: MemorySpec) -> None:
        self.memory = Memory(spec)
        self.phi = np.empty(spec.dim)  # the fast path's features of the tick
        self.reset()

    def reset(self) -> None:
        self.memory.reset()
        self.state = START
        self.ticks = 0
        self.command: FloatArray | None = None

    def features(self, x: FloatArray) -> FloatArray:
        self.memory.update(x, self.command)
        return self.memory.features(x, self.ticks)

    def kernel_args(self, x: FloatArray) -> AdvanceArgs:
        """:func:`.jit_fsm.advance`'s arguments for this tick, up to the features' buffer."""
        m = self.memory
        cmd = _NO_COMMAND if self.command is None else self.command
        return (x, cmd, self.command is not None, m.blob_x, m.proprio, m.offset, m.scale,
                m.config, m.buffer, self.ticks, self.phi)

    def enter(self, state: int) -> None:
        self.ticks = self.ticks + 1 if state == self.state else 0
        self.state = state


class LearnedFSM:
    """Learned transitions over a ROGER model's experts (module docstring).

    Parameters
    ----------
    spec : MemorySpec
        The robot's layout for the memories (:func:`roger_daemon.fsm.profiles.aibo_memory`).
    transitions : TransitionModel, optional
        A learned model to continue from; a new one by default.
    fast : bool
        Learn and choose by the compiled kernels (:mod:`.jit_fsm`, the default) or by the
        readable numpy code they are tested against (``False``): the same memories and
        statistics, bit for bit.
    """

    def __init__(self, spec: MemorySpec, transitions: TransitionModel | None = None,
                 fast: bool = True) -> None:
        self.spec = spec
        self.fast = fast
        self.transitions = transitions or TransitionModel(spec.dim)
        if self.transitions.dim != spec.dim:
            raise ValueError(f"LearnedFSM: the transitions have dim {self.transitions.dim}, the "
                             f"spec {spec.dim}")
        self._learn = _Track(spec)
        self._act = _Track(spec)
        self.n_observed = 0

    # -- learning ----------------------------------------------------------------------------

    def observe(self, x: npt.ArrayLike, y: npt.ArrayLike, state: int,
                episode_start: bool = False, *, learn_start: bool = True) -> None:
        """One demonstrated tick: perception ``x``, executed action ``y``, its expert ``state``
        (``< 0``: none; the tick still advances the memories). ``learn_start=False``: an
        episode's first state is entered without teaching the start row (a stream whose
        episode boundaries are unknown: :mod:`.online`)."""
        xv = np.ascontiguousarray(x, dtype=np.float64)
        yv = np.ascontiguousarray(y, dtype=np.float64)
        track = self._learn
        if episode_start:
            track.reset()
        teach = state >= 0 and (learn_start or track.state != START)
        if self.fast:
            self._observe_fast(track, xv, int(state) if teach else None)
        else:
            phi = track.features(xv)
            if teach:
                self.transitions.learn_one(track.state, int(state), phi)
        if state >= 0:
            track.enter(int(state))
        track.command = yv
        self.n_observed += 1

    def _observe_fast(self, track: _Track, x: FloatArray, state: int | None) -> None:
        """The memories, features and (``state`` given) the pair's update in one kernel call;
        a pair seen for the first time by :meth:`TransitionModel.learn_one`."""
        from roger_daemon.fsm import jit_fsm

        tr = self.transitions
        r = -1 if state is None else tr._index.get((track.state, state), -1)
        buf = tr._buf
        finite = jit_fsm.observe(*track.kernel_args(x), r, buf["count"], buf["mu"],
                                 buf["lam"], buf["valid"], tr.kappa0)
        if state is None:
            return
        if r < 0:
            tr.learn_one(track.state, state, track.phi)
        elif not finite:
            raise ValueError(f"TransitionModel: phi must be {tr.dim} finite floats")
        else:
            tr.learned(r)

    # -- acting ------------------------------------------------------------------------------

    @property
    def state(self) -> int:
        """The acting side's current state (an expert id; ``-1`` before the first tick)."""
        return self._act.state

    def reset(self) -> None:
        """A new episode for the acting side."""
        self._act.reset()

    def choose(self, x: npt.ArrayLike, table: Any) -> int:
        """The row of ``table`` (a :class:`~roger_daemon.learner.prediction.MultimapTable` at
        ``x``) the robot acts on this tick; enters that expert's state. ``-1``: empty table."""
        if not table.expert_ids:
            return -1
        xv = np.ascontiguousarray(x, dtype=np.float64)
        track = self._act
        if self.fast:
            row = self._choose_fast(track, xv, table)
        else:
            phi = track.features(xv)
            row = self._best_row(track.state, phi, table)
            if row < 0:
                row = self._best_row(START, phi, table)
            if row < 0:  # no learned successor in the multimap: the paper's gate argmax
                row = int(np.argmax(np.asarray(table.gate_probs)))
        track.enter(int(table.expert_ids[row]))
        return row

    def commit(self, command: npt.ArrayLike) -> None:
        """The command actually executed this tick (the memories' odometry and clocks)."""
        self._act.command = np.ascontiguousarray(command, dtype=np.float64)

    def act(self, x: npt.ArrayLike, table: Any) -> FloatArray:
        """:meth:`choose`, then the chosen expert's mean as the command (committed)."""
        row = self.choose(x, table)
        command = (np.zeros(table.means.shape[1]) if row < 0
                   else np.array(table.means[row], dtype=np.float64))
        self.commit(command)
        return command

    def _choose_fast(self, track: _Track, x: FloatArray, table: Any) -> int:
        """:meth:`choose`'s row by :func:`.jit_fsm.choose` (one call)."""
        from roger_daemon.fsm import jit_fsm

        tr = self.transitions
        buf = tr._buf
        return int(jit_fsm.choose(
            *track.kernel_args(x), tr.source_rows(track.state), tr.source_rows(START),
            buf["pairs"], buf["count"], buf["mu"], buf["lam"], buf["linv"], buf["lnorm"],
            buf["valid"], tr.kappa0, tr.nu0, np.asarray(table.expert_ids, dtype=np.int64),
            np.asarray(table.gate_probs, dtype=np.float64),
            np.asarray(table.n_points, dtype=np.int64)))

    def _best_row(self, prev: int, phi: FloatArray, table: Any) -> int:
        states, scores = self.transitions.log_scores(prev, phi)
        if states.size == 0:
            return -1
        rows = {int(e): r for r, e in enumerate(table.expert_ids)}
        # log g_j(x) up to a constant: gate probability over count (p(k | x) ∝ n_k t_k(x)),
        # floored so that an expert without gate mass (min_support) is merely very unlikely
        gate = np.log(np.maximum(np.asarray(table.gate_probs, dtype=np.float64), GATE_FLOOR))
        gate -= np.log(np.maximum(1.0, np.asarray(table.n_points, dtype=np.float64)))
        best, best_row = -math.inf, -1
        for state, score in zip(states.tolist(), scores.tolist(), strict=True):
            r = rows.get(state)
            if r is not None and score + gate[r] > best:
                best, best_row = score + gate[r], r
        return best_row

    # -- state -------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, np.ndarray]:
        """Named arrays and JSON metadata, no objects: the transitions, the learning stream's
        memory and position (learning continues exactly after a reload)."""
        import json

        out = {f"transitions.{k}": v for k, v in self.transitions.state_arrays().items()}
        out.update({f"memory.{k}": v for k, v in self._learn.memory.state_arrays().items()})
        last = self._learn.command
        meta = {"schema": SCHEMA, "kind": "roger.fsm", "spec": spec_to_mapping(self.spec),
                "state": self._learn.state, "ticks": self._learn.ticks,
                "n_observed": self.n_observed, "has_command": last is not None}
        out["command"] = np.zeros(0) if last is None else last.copy()
        out["meta"] = np.array(json.dumps(meta, sort_keys=True))
        return out

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> LearnedFSM:
        """Rebuild from :meth:`state_dict` (or ``np.load`` of it)."""
        import json

        meta = json.loads(str(np.asarray(state["meta"])))
        if meta.get("kind") != "roger.fsm" or int(meta.get("schema", 0)) > SCHEMA:
            raise ValueError(f"not a learned-FSM state (kind {meta.get('kind')!r}, schema "
                             f"{meta.get('schema')!r})")
        arrays = {k.split(".", 1)[1]: np.asarray(v) for k, v in state.items()
                  if k.startswith("transitions.")}
        fsm = cls(spec_from_mapping(meta["spec"]), TransitionModel.from_arrays(arrays))
        fsm._learn.memory.load_arrays({k.split(".", 1)[1]: np.asarray(v)
                                       for k, v in state.items() if k.startswith("memory.")})
        fsm._learn.state = int(meta["state"])
        fsm._learn.ticks = int(meta["ticks"])
        fsm._learn.command = (np.asarray(state["command"], dtype=np.float64).copy()
                              if meta["has_command"] else None)
        fsm.n_observed = int(meta["n_observed"])
        return fsm

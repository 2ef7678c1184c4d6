"""The experiment in one process: demonstrations, training and closed-loop evaluation, no Zenoh.

Same simulator (:class:`simulator.episodes.SoccerSim`), same demonstrator
(:class:`simulator.controllers.hcc.HCC`), same learners and the same transitioner rule
(:func:`simulator.controllers.transitioner.choose_expert`) as the Zenoh path of ``roger experiment
goal-scoring``; the only difference is that perceptions, predictions and commands are function
calls instead of messages. Given the same seeds both paths give the same episodes (a test
checks it on a shared subset), so this path serves iteration and ablations
(``docs/goal-scoring.md``) while the Zenoh path stays the reference.

Controllers (all act on the 23-D perception only):

* :class:`TransitionerController`: the HCC decides the subtask, the learned experts act (paper
  section IV: "the HCC's transition model ... selects among the learned experts"); also for
  ROGER's experts merged per group (:func:`simulator.experiment.pipeline.merge_expert_groups`).
* :class:`OracleController`: the **segmentation oracle**: one sparse online GP per true
  subtask (trained on that subtask's demonstrations), the same HCC transitions. The
  demonstrator's labels group its data, so it is a ceiling for ROGER, never part of ROGER.
* :class:`MeanController`: the unimap GP's mean drives the robot (the paper's DPA).
* :class:`AutonomousController`: ROGER's experts chosen by learned transitions
  (:class:`roger_daemon.fsm.LearnedFSM`), no hand-coded code and no label at run time
  (docs/autonomy.md).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocols import ExpertOutput
from protocols.aibo import DIMS
from simulator.controllers.demo_noise import DemoNoise
from simulator.controllers.hcc import HCC
from simulator.controllers.transitioner import DEFAULT_RULE, transition_command
from simulator.episodes import EpisodeResult, SoccerSim, StartLocation, run_episode
from simulator.experiment.averaging import MultimapNeighbourhood
from simulator.experiment.training import Demonstrations

__all__ = [
    "AutonomousController",
    "EpisodeRecord",
    "MeanController",
    "OracleController",
    "TransitionerController",
    "demonstrate",
    "evaluate",
    "failure_mode",
    "fit_oracle",
]


def demonstrate(sim: SoccerSim, hcc: HCC, locations: Sequence[int], shots: int, seed: int,
                starts: Sequence[StartLocation] | None = None, noise: DemoNoise | None = None
                ) -> tuple[Demonstrations, list[EpisodeRecord]]:
    """The HCC demonstrating ``shots`` episodes from each location (repetition = shot index).

    Pairs in learning order: location by location, shot by shot, tick by tick; and each
    demonstration's outcome (failures are demonstrations too, as in the paper).  With
    ``noise`` the robot executes the HCC's command disturbed, the HCC's own command is the
    pair's action (:mod:`simulator.controllers.demo_noise`).
    """
    records: list[EpisodeRecord] = []
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    executed: list[np.ndarray] = []
    labels: list[str] = []
    locs: list[int] = []
    ticks: list[int] = []
    for loc in locations:
        for shot in range(shots):
            rec = _Recorder(hcc, noise)
            res = run_episode(sim, rec, loc, seed, shot, start=_start(starts, loc))
            records.append(EpisodeRecord.of(res))
            xs.extend(rec.x)
            ys.extend(rec.y)
            executed.extend(rec.executed)
            labels.extend(rec.labels)
            locs.extend([loc] * len(rec.x))
            ticks.extend(range(len(rec.x)))
    data = Demonstrations(np.array(xs).reshape(-1, DIMS.x), np.array(ys).reshape(-1, DIMS.y),
                          labels, np.array(locs, dtype=np.int64),
                          np.array(ticks, dtype=np.int64), 0,
                          None if noise is None else np.array(executed).reshape(-1, DIMS.y))
    return data, records


def _start(starts: Sequence[StartLocation] | None, loc: int) -> StartLocation | None:
    return None if starts is None else starts[loc]


class _Recorder:
    """The HCC as demonstrator, keeping every (perception, action, label)."""

    def __init__(self, hcc: HCC, noise: DemoNoise | None = None) -> None:
        self.hcc = hcc
        self.noise = noise
        self.x: list[np.ndarray] = []
        self.y: list[np.ndarray] = []
        self.executed: list[np.ndarray] = []
        self.labels: list[str] = []

    def reset(self) -> None:
        self.hcc.reset()
        if self.noise is not None:
            self.noise.reset()

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        y, label = self.hcc.decide(x)
        executed = y if self.noise is None else self.noise(y)
        self.hcc.commit(executed)  # the HCC's odometry follows what the robot did
        self.x.append(np.asarray(x, dtype=np.float64))
        self.y.append(np.asarray(y, dtype=np.float64))
        self.executed.append(np.asarray(executed, dtype=np.float64))
        self.labels.append(label)
        return executed, label


def fit_oracle(stream: Demonstrations, make_gp: Callable[[np.ndarray], Any]) -> dict[str, Any]:
    """The segmentation oracle: one GP per true subtask, learning that subtask's points in order.

    ``make_gp(y_of_subtask)`` builds an empty GP (it may use the subtask's outputs, e.g. for a
    prior mean); labels only group the data here, as in the paper's section IV.A grouping.
    """
    lab = np.asarray(stream.labels)
    gps: dict[str, Any] = {}
    for label in sorted(set(stream.labels)):
        idx = np.flatnonzero(lab == label)
        gp = make_gp(stream.y[idx])
        for i in idx:
            gp.learn_one(stream.x[i], stream.y[i])
        gps[label] = gp
    return gps


class TransitionerController:
    """ROGER's experts, chosen by the HCC's current subtask (``roger hcc --role transitioner``)."""

    def __init__(self, hcc: HCC, model: Any, expert_labels: Mapping[int, str],
                 rule: str = DEFAULT_RULE) -> None:
        self.hcc = hcc
        self.model = model
        self.labels = dict(expert_labels)
        self.rule = rule
        self.counts: Counter[str] = Counter()

    def reset(self) -> None:
        """Start an episode: the FSM back to its initial state."""
        self.hcc.reset()

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """One tick: the FSM's subtask, the chosen expert's mean as the command."""
        _, subtask = self.hcc.decide(x)
        multimap = tuple(
            ExpertOutput(expert=int(e.expert_id), p=float(e.gate_prob), mean=e.mean, var=e.var,
                         n=int(e.n_points), label=self.labels.get(int(e.expert_id), ""))
            for e in self.model.predict_multimap(x)
        )
        fallback = None if multimap else np.asarray(self.model.predict_one(x).mean)
        y, how, _ = transition_command(multimap, fallback, subtask, self.rule)
        self.counts[how] += 1
        y = _finite(y, x, self.counts)
        self.hcc.commit(y)
        return y, subtask


class OracleController:
    """One GP per true subtask, chosen by the HCC's current subtask (the segmentation oracle)."""

    def __init__(self, hcc: HCC, gps: Mapping[str, Any]) -> None:
        self.hcc = hcc
        self.gps = dict(gps)
        self.counts: Counter[str] = Counter()

    def reset(self) -> None:
        """Start an episode: the FSM back to its initial state."""
        self.hcc.reset()

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """One tick: the FSM's subtask, that subtask's GP mean as the command."""
        y_hcc, subtask = self.hcc.decide(x)
        gp = self.gps.get(subtask)
        if gp is None:  # a subtask never demonstrated: hold still (counted)
            self.counts["no_expert"] += 1
            y = hold_command(x)
        else:
            self.counts["label"] += 1
            y = _finite(np.asarray(gp.predict_one(x).mean, dtype=np.float64), x, self.counts)
        self.hcc.commit(y)
        return y, subtask


class AutonomousController:
    """ROGER's experts chosen by the learned transitions: the robot plays alone.

    Each tick: the model's multimap at ``x`` (one ``predict_table``), the learned FSM's choice
    among its experts, that expert's mean as the command (``LearnedFSM.act``). The label it
    returns is the chosen expert (``fsm:<id>``), never a demonstrator's subtask."""

    def __init__(self, model: Any, fsm: Any) -> None:
        self.model = model
        self.fsm = fsm
        self.counts: Counter[str] = Counter()

    def reset(self) -> None:
        """Start an episode: the FSM's acting side back to its start state."""
        self.fsm.reset()

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """One tick: the learned state's expert mean as the command."""
        _, table = self.model.predict_table(x)
        y = self.fsm.act(x, table)
        if not np.all(np.isfinite(y)):
            self.counts["non_finite"] += 1
            y = hold_command(x)
            self.fsm.commit(y)
        self.counts["learned"] += 1
        return y, f"fsm:{self.fsm.state}"


class MeanController:
    """The unimap GP's predictive mean is the command (``roger experiment dpa``).

    With ``neighbourhood`` (the demonstrations it learned) it keeps the episode's perceptions
    and commands and :meth:`averaging` says how much of the episode averaged the multimap
    (:mod:`simulator.experiment.averaging`)."""

    def __init__(self, model: Any, neighbourhood: MultimapNeighbourhood | None = None) -> None:
        self.model = model
        self.neighbourhood = neighbourhood
        self.counts: Counter[str] = Counter()
        self._xs: list[np.ndarray] = []
        self._commands: list[np.ndarray] = []

    def reset(self) -> None:
        """Start an episode (the unimap GP keeps no episode state; the trace restarts)."""
        self._xs.clear()
        self._commands.clear()

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """One tick: the unimap GP's mean as the command, no subtask."""
        y = _finite(np.asarray(self.model.predict_one(x).mean, dtype=np.float64), x, self.counts)
        if self.neighbourhood is not None:
            self._xs.append(np.array(x, dtype=np.float64))
            self._commands.append(y)
        return y, ""

    def averaging(self) -> dict[str, float]:
        """``aliased_share``/``averaged_share`` of the episode so far ({} without data)."""
        if self.neighbourhood is None or not self._xs:
            return {}
        return self.neighbourhood.episode_summary(np.array(self._xs), np.array(self._commands))


@dataclass
class EpisodeRecord:
    """One evaluated episode: outcome, counters and how the robot moved."""

    location: int
    repetition: int
    outcome: str
    success: bool
    sim_time_s: float
    ticks: int
    counters: dict[str, int] = field(default_factory=dict)
    path_m: float = 0.0
    ball_path_m: float = 0.0
    #: the DPA's averaging measure (:mod:`simulator.experiment.averaging`), when measured
    averaging: dict[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, res: EpisodeResult, averaging: Mapping[str, float] | None = None
           ) -> EpisodeRecord:
        """The record of a finished episode of the simulator."""
        return cls(res.location, res.repetition, res.outcome, res.success, res.sim_time_s,
                   res.ticks, dict(res.counters), res.path_m, res.ball_path_m,
                   dict(averaging or {}))

    @property
    def failure_mode(self) -> str:
        """How the episode ended, in words (:func:`failure_mode`)."""
        return failure_mode(self.outcome, self.counters, self.path_m)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON record of the episode."""
        return {
            "location": self.location, "repetition": self.repetition, "outcome": self.outcome,
            "success": self.success, "sim_time_s": round(self.sim_time_s, 3),
            "ticks": self.ticks, **{k: int(v) for k, v in self.counters.items()},
            "path_m": round(self.path_m, 3), "ball_path_m": round(self.ball_path_m, 3),
            "failure_mode": self.failure_mode, **self.averaging,
        }


#: Below this walked distance (m) over a whole failed episode the robot "stood still".
STILL_PATH_M = 0.3


def failure_mode(outcome: str, counters: Mapping[str, int], path_m: float | None) -> str:
    """How an episode ended, in words a reader of the ablation table can use.

    ``stands still`` (walked < 0.3 m, measured by the simulator on either path), ``ball out`` /
    ``own goal``,
    ``never traps`` (no trap motion), ``traps fail`` (motions, no capture), ``kicks in place``
    (kick motions without a captured ball), ``no kick after trap`` and ``kicks, misses``.
    """
    if outcome == "goal":
        return "goal"
    if outcome == "out":
        return "ball out"
    if outcome == "own_goal":
        return "own goal"
    if path_m is not None and path_m < STILL_PATH_M:
        return "stands still"
    traps, ok, kicks = (int(counters.get(k, 0)) for k in ("traps", "traps_ok", "kicks"))
    if kicks and not ok:
        return "kicks in place"
    if not traps:
        return "never traps"
    if not ok:
        return "traps fail"
    if not kicks:
        return "no kick after trap"
    return "kicks, misses"


def hold_command(x: np.ndarray) -> np.ndarray:
    """Stand still with head and tail where they are (what ``roger hcc`` sends without a
    prediction)."""
    y = np.zeros(DIMS.y)
    y[3:8] = x[18:23]
    return y


def _finite(y: np.ndarray, x: np.ndarray, counts: Counter[str]) -> np.ndarray:
    """``y``, or a hold command (counted as ``non_finite``) if a learner returned NaN/inf."""
    if np.all(np.isfinite(y)):
        return y
    counts["non_finite"] += 1
    return hold_command(x)


def evaluate(sim: SoccerSim, controller: Any, locations: Sequence[int], attempts: int,
             seed: int, starts: Sequence[StartLocation] | None = None,
             on_episode: Callable[[EpisodeRecord], None] | None = None) -> list[EpisodeRecord]:
    """``attempts`` episodes (repetitions 0..attempts-1) from each location, in order."""
    out = []
    for loc in locations:
        for rep in range(attempts):
            res = run_episode(sim, controller, loc, seed, rep, start=_start(starts, loc))
            averaging = controller.averaging() if hasattr(controller, "averaging") else None
            rec = EpisodeRecord.of(res, averaging)
            out.append(rec)
            if on_episode is not None:
                on_episode(rec)
    return out

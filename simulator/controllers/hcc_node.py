"""``roger hcc``: the hand-coded FSM as a Zenoh process, demonstrator or transitioner.

* ``--role demonstrator``: for every perception(t), publishes ``action``(t) (the FSM's 9-D
  action with its subtask ``label``) and ``command``(t) (the same vector, ``source =
  "hcc:demonstrator:<subtask>"``), which drives the robot.
* ``--role transitioner``: runs the FSM on perception(t) to know the current subtask, takes
  the daemon's ``prediction``(t) (``--prediction-timeout`` seconds at most, matched by tick;
  in ``--clock realtime`` the newest prediction not older than ``--max-prediction-age`` ticks),
  and publishes as ``command``(t) the mean of the expert whose ``label`` is that subtask with
  the most points (``--rule support``, default), the lowest predictive variance (``--rule
  variance``) or the highest gate probability ``p`` (``--rule gate``).
  ``source = "hcc:transitioner:<subtask>:<expert>:<how>"``
  where ``how`` is ``label`` or a fallback:

  - ``fallback_top``: no expert carries that label -> the highest-``p`` expert overall;
  - ``fallback_mean``: the multimap is empty -> the prediction's own ``mean``;
  - ``no_prediction``: nothing arrived in time -> a hold command (stand still, head and tail
    where they are, no motion).

  Each case is counted; the counts are printed on exit. The FSM is told which command was
  executed (:meth:`simulator.controllers.hcc.HCC.commit`); it never publishes ``action``.

A perception with ``t == 0`` starts a new episode (the FSM is reset). A repeated perception
tick (the lockstep simulator re-sends when a command is late) gets the cached command again
without stepping the FSM. With ``--exit-when-done`` the process exits when the simulator
publishes its final ``end`` event (``data.run_complete``); otherwise it runs until SIGTERM/SIGINT.
On exit it prints one JSON line of counters (also to ``--stats FILE``).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from typing import Any

import numpy as np

from protocols import Action, Command, EpisodeEvent, Perception, Prediction, keys
from protocols.aibo import DIMS
from roger_daemon.tools.common import count, seconds
from simulator.config import load_config
from simulator.controllers.hcc import HCC, HCCParams, HeadModel
from simulator.controllers.transitioner import DEFAULT_RULE, RULES, transition_command
from simulator.sim_node import DAEMON_ENDPOINT, DEFAULT_LISTEN
from simulator.transport import (
    EPHEMERAL,
    InvalidCounter,
    StopFlag,
    Subscription,
    add_zenoh_args,
    publisher,
    put,
    serve,
    wait_for,
)

__all__ = ["configure", "hcc_from_config", "run"]

log = logging.getLogger("roger.hcc")


def configure(parser: argparse.ArgumentParser) -> None:
    """Command-line arguments of ``roger hcc``."""
    parser.add_argument("--role", choices=("demonstrator", "transitioner"), default="demonstrator",
                        help="demonstrator: the FSM drives and publishes its actions to learn "
                             "from (default); transitioner: executes the daemon's predictions")
    parser.add_argument("--robot", default="aibo", help="robot id in the key expressions")
    parser.add_argument(
        "--clock",
        choices=("lockstep", "realtime"),
        default="lockstep",
        help="how the transitioner matches predictions to perceptions",
    )
    parser.add_argument(
        "--config", default=None, help="task TOML (its [sim] camera/robot/motion, [hcc])"
    )
    parser.add_argument(
        "--prediction-timeout",
        type=seconds,
        default=2.0,
        help="transitioner, lockstep: seconds to wait for prediction(t)",
    )
    parser.add_argument(
        "--max-prediction-age",
        type=count,
        default=3,
        help="transitioner, realtime: newest prediction at most this many ticks old",
    )
    parser.add_argument(
        "--exit-when-done", action="store_true", help="exit when the simulator's run is complete"
    )
    parser.add_argument(
        "--idle-exit",
        type=seconds,
        default=0.0,
        help="exit after this many seconds without perception (0: never)",
    )
    parser.add_argument(
        "--rule",
        choices=RULES,
        default=DEFAULT_RULE,
        help="transitioner: among the subtask's experts, the gate-weighted mean of all "
        f"(mixture, default {DEFAULT_RULE}), the one with the most points (support), the "
        "lowest predictive variance, or the highest gate probability",
    )
    parser.add_argument("--stats", default=None, help="write the exit counters (JSON) here")
    add_zenoh_args(parser, listen=(EPHEMERAL,), connect=(DEFAULT_LISTEN, DAEMON_ENDPOINT))


def hcc_from_config(path: str | None) -> HCC:
    """The HCC of a task TOML (its [sim] robot/camera/motion and [hcc] table; None: defaults)."""
    cfg = load_config(path)
    params = HCCParams(
        attack=cfg.field.attack, hz=cfg.episode.control_hz, ball_radius=cfg.ball.radius
    )
    if path:
        import tomllib

        with open(path, "rb") as f:
            data = tomllib.load(f)
        table = data.get("hcc", {})
        if table:
            from dataclasses import fields, replace

            known = {f.name for f in fields(HCCParams)}
            bad = sorted(set(table) - known)
            if bad:
                raise ValueError(f"unknown [hcc] keys {bad}")
            conv: dict[str, Any] = {
                k: (tuple(v) if isinstance(v, list) else v) for k, v in table.items()
            }
            params = replace(params, **conv)
    return HCC(params, HeadModel(cfg.robot, cfg.camera), cfg.motion)


class HCCNode:
    """One session, one loop."""

    def __init__(self, args: argparse.Namespace, hcc: HCC, stop: StopFlag) -> None:
        self.args = args
        self.hcc = hcc
        self.stop = stop
        self.robot = keys.validate_robot_id(args.robot)
        self.invalid = InvalidCounter("hcc")
        self.counts: dict[str, int] = {
            "perceptions": 0,
            "commands": 0,
            "resent": 0,
            "stale_perceptions": 0,
            "episodes": 0,
            "label": 0,
            "fallback_top": 0,
            "fallback_mean": 0,
            "no_prediction": 0,
        }
        self.subtask_ticks: dict[str, int] = {}
        self.last_tick = -1
        self.last_command: Command | None = None
        self._pred_cache: Prediction | None = None

    def run(self, session: Any) -> dict[str, Any]:
        transitioner = self.args.role == "transitioner"
        self.perc = Subscription(session, self.robot, "perception", DIMS, self.invalid,
                                 capacity=256)
        self.events = Subscription(session, self.robot, "episode", None, self.invalid, capacity=256)
        self.preds = (
            Subscription(session, self.robot, "prediction", DIMS, self.invalid, capacity=64)
            if transitioner
            else None
        )
        self.pub_cmd = publisher(session, keys.command(self.robot))
        self.pub_act = None if transitioner else publisher(session, keys.action(self.robot))
        last_seen = time.monotonic()
        done = False
        while not self.stop.stopped and not done:
            msg = wait_for(self.perc.poll, 0.1, self.stop)
            for ev in self.events.drain():
                assert isinstance(ev, EpisodeEvent)
                if ev.event == "end" and ev.data.get("run_complete") and self.args.exit_when_done:
                    done = True
            if msg is None:
                if self.args.idle_exit > 0 and time.monotonic() - last_seen > self.args.idle_exit:
                    log.info("no perception for %.1f s; exiting", self.args.idle_exit)
                    break
                continue
            last_seen = time.monotonic()
            assert isinstance(msg, Perception)
            self._on_perception(msg)
        for inbox in (self.perc, self.events, self.preds):
            if inbox is not None:
                inbox.close()
        return {
            "role": self.args.role,
            "robot": self.robot,
            **self.counts,
            "subtask_ticks": self.subtask_ticks,
            "invalid_messages": self.invalid.total(),
            "invalid_by_reason": dict(self.invalid.counts),
        }

    def _on_perception(self, msg: Perception) -> None:
        self.counts["perceptions"] += 1
        new_episode = msg.t == 0.0 and msg.tick != self.last_tick
        if not new_episode and msg.tick == self.last_tick and self.last_command is not None:
            self.counts["resent"] += 1
            put(self.pub_cmd, self.last_command)
            return
        if not new_episode and msg.tick < self.last_tick:
            self.counts["stale_perceptions"] += 1
            return
        if new_episode:
            self.hcc.reset()
            self.counts["episodes"] += 1
        self.last_tick = msg.tick
        y, label = self.hcc.decide(np.asarray(msg.x))
        self.subtask_ticks[label] = self.subtask_ticks.get(label, 0) + 1
        if self.pub_act is not None:
            put(self.pub_act, Action(self.robot, msg.tick, msg.t, y=y, label=label))
            cmd = Command(self.robot, msg.tick, msg.t, y=y, source=f"hcc:demonstrator:{label}")
        else:
            y, source = self._transition(msg, label)
            cmd = Command(self.robot, msg.tick, msg.t, y=y, source=source)
        self.hcc.commit(np.asarray(cmd.y))
        self.last_command = cmd
        put(self.pub_cmd, cmd)
        self.counts["commands"] += 1

    def _prediction_for(self, msg: Perception) -> Prediction | None:
        assert self.preds is not None
        lockstep = self.args.clock == "lockstep"

        def newest() -> Prediction | None:
            for m in self.preds.drain() if self.preds is not None else []:
                assert isinstance(m, Prediction)
                if self._pred_cache is None or m.tick >= self._pred_cache.tick:
                    self._pred_cache = m
            c = self._pred_cache
            if c is None:
                return None
            if lockstep:
                return c if c.tick == msg.tick else None
            return c if 0 <= msg.tick - c.tick <= self.args.max_prediction_age else None

        if lockstep:
            got: Prediction | None = wait_for(newest, self.args.prediction_timeout, self.stop)
            return got
        return newest()

    def _transition(self, msg: Perception, subtask: str) -> tuple[np.ndarray, str]:
        pred = self._prediction_for(msg)
        if pred is None:
            self.counts["no_prediction"] += 1
            y = np.zeros(DIMS.y)
            y[3:8] = np.asarray(msg.x)[18:23]
            return y, f"hcc:transitioner:{subtask}:-1:no_prediction"
        y, how, expert = transition_command(pred.multimap, np.asarray(pred.mean), subtask,
                                            self.args.rule)
        self.counts[how] += 1
        shown = pred.expert if expert < 0 else expert
        return y, f"hcc:transitioner:{subtask}:{shown}:{how}"


def run(args: argparse.Namespace) -> int:
    """Serve until stopped (or the simulator's run is complete); print the counters."""
    try:
        hcc = hcc_from_config(args.config)
    except (ValueError, OSError, TypeError) as exc:
        print(f"roger hcc: {exc}", file=sys.stderr)
        return 2
    serve(HCCNode(args, hcc, StopFlag()), args)
    return 0

"""``roger hcc``: the hand-coded FSM as a Zenoh process, demonstrator or transitioner.

* ``--role demonstrator``: for every perception(t), publishes ``action``(t) (the FSM's 9-D
  action with its subtask ``label``) and ``command``(t) (the same vector, ``source =
  "hcc:demonstrator:<subtask>"``), which drives the robot. With ``--demo-noise F`` (DART,
  :mod:`simulator.controllers.demo_noise`) the robot is driven by that vector disturbed, and
  ``action`` stays the FSM's own: the demonstrations visit the states a learner's errors
  lead to, and teach how the demonstrator recovers from them.
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
from typing import Any

import numpy as np

from protocols import Action, Command, Perception, keys
from simulator.config import load_config
from simulator.controllers.demo_noise import DemoNoise, seeded
from simulator.controllers.hcc import HCC, HCCParams, HeadModel
from simulator.controllers.node import PerceptionNode, add_node_args, hold
from simulator.controllers.transitioner import DEFAULT_RULE, RULES, transition_command
from simulator.transport import StopFlag, publisher, put, serve

__all__ = ["configure", "hcc_from_config", "run"]

log = logging.getLogger("roger.hcc")


def configure(parser: argparse.ArgumentParser) -> None:
    """Command-line arguments of ``roger hcc``."""
    parser.add_argument("--role", choices=("demonstrator", "transitioner"), default="demonstrator",
                        help="demonstrator: the FSM drives and publishes its actions to learn "
                             "from (default); transitioner: executes the daemon's predictions")
    parser.add_argument(
        "--config", default=None, help="task TOML (its [sim] camera/robot/motion, [hcc])"
    )
    parser.add_argument(
        "--rule",
        choices=RULES,
        default=DEFAULT_RULE,
        help="transitioner: among the subtask's experts, the gate-weighted mean of all "
        f"(mixture, default {DEFAULT_RULE}), the one with the most points (support), the "
        "lowest predictive variance, or the highest gate probability",
    )
    parser.add_argument("--demo-noise", type=float, default=0.0, metavar="F",
                        help="demonstrator: drive the robot with the FSM's walk and head "
                             "commands disturbed by F x each range (0-0.5, held 0.5 s; "
                             "default 0: undisturbed); the FSM's own command is published "
                             "to learn from")
    parser.add_argument("--demo-noise-seed", type=int, default=0, metavar="N",
                        help="the disturbance's seed (default 0)")
    add_node_args(parser, who="transitioner")


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


class HCCNode(PerceptionNode):
    """The FSM's step in the nodes' one loop (:mod:`simulator.controllers.node`)."""

    def __init__(self, args: argparse.Namespace, hcc: HCC, stop: StopFlag,
                 noise: DemoNoise | None = None) -> None:
        super().__init__(args, stop, args.role, log,
                         ("label", "fallback_top", "fallback_mean", "no_prediction"), "hcc")
        self.hcc = hcc
        self.noise = noise
        self.subtask_ticks: dict[str, int] = {}
        self.pub_act: Any = None

    def run(self, session: Any) -> dict[str, Any]:
        transitioner = self.args.role == "transitioner"
        if not transitioner:
            self.pub_act = publisher(session, keys.action(self.robot))
        self.serve_perceptions(session, predictions=transitioner)
        noise = 0.0 if self.noise is None else self.noise.scale
        return self.summary(subtask_ticks=self.subtask_ticks, demo_noise=noise)

    def new_episode(self) -> None:
        """The FSM restarts (and the disturbance is redrawn)."""
        self.hcc.reset()
        if self.noise is not None:
            self.noise.reset()

    def command_for(self, msg: Perception) -> Command:
        """The FSM's action (demonstrator) or the expert of its subtask (transitioner)."""
        y, label = self.hcc.decide(np.asarray(msg.x))
        self.subtask_ticks[label] = self.subtask_ticks.get(label, 0) + 1
        if self.pub_act is not None:
            put(self.pub_act, Action(self.robot, msg.tick, msg.t, y=y, label=label))
            executed = y if self.noise is None else self.noise(y)
            cmd = Command(self.robot, msg.tick, msg.t, y=executed,
                          source=f"hcc:demonstrator:{label}")
        else:
            y, source = self._transition(msg, label)
            cmd = Command(self.robot, msg.tick, msg.t, y=y, source=source)
        self.hcc.commit(np.asarray(cmd.y))
        return cmd

    def _transition(self, msg: Perception, subtask: str) -> tuple[np.ndarray, str]:
        pred = self.prediction_for(msg)
        if pred is None:
            self.counts["no_prediction"] += 1
            return hold(np.asarray(msg.x)), f"hcc:transitioner:{subtask}:-1:no_prediction"
        y, how, expert = transition_command(pred.multimap, np.asarray(pred.mean), subtask,
                                            self.args.rule)
        self.counts[how] += 1
        shown = pred.expert if expert < 0 else expert
        return y, f"hcc:transitioner:{subtask}:{shown}:{how}"


def _noise(args: argparse.Namespace) -> DemoNoise | None:
    """The demonstrator's disturbance of ``--demo-noise``; ValueError naming a bad value."""
    try:
        noise = seeded(args.demo_noise, args.demo_noise_seed)
    except ValueError as exc:
        raise ValueError(f"--demo-noise {args.demo_noise!r}: {exc}") from None
    if noise is not None and args.role != "demonstrator":
        raise ValueError(f"--demo-noise {args.demo_noise!r}: only the demonstrator is "
                         f"disturbed, not --role {args.role}")
    return noise


def run(args: argparse.Namespace) -> int:
    """Serve until stopped (or the simulator's run is complete); print the counters."""
    try:
        noise = _noise(args)
        hcc = hcc_from_config(args.config)
    except (ValueError, OSError, TypeError) as exc:
        print(f"roger hcc: {exc}", file=sys.stderr)
        return 2
    serve(HCCNode(args, hcc, StopFlag(), noise), args)
    return 0

"""The one loop of the controller nodes (``roger hcc``, ``roger play``, ``roger experiment dpa``).

Each node subscribes to the robot's ``episode`` events and to one driving inbox
(``perception``, or ``prediction`` for the DPA), and answers every message it takes from that
inbox; it exits on the simulator's final ``end`` event (``data.run_complete``) with
``--exit-when-done``, after ``--idle-exit`` seconds without a message, or on SIGTERM/SIGINT,
and reports its counters as one JSON line (docs/autonomy.md, docs/experiments.md).

:class:`PerceptionNode` is the perception-driven part they share: perception(t) with
``t == 0`` starts a new episode, a repeated tick gets the cached command again, an older tick
is counted stale, and :meth:`PerceptionNode.prediction_for` takes the daemon's
``prediction``(t) by tick in lockstep or the newest not older than ``--max-prediction-age``
ticks in realtime. A node supplies only its "command for this perception" step.

Nothing here imports :mod:`simulator.controllers.hcc` (``roger play`` must run without it;
``tests/test_play_node.py`` walks the import graph).
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from protocols import Command, EpisodeEvent, Perception, Prediction, keys
from protocols.aibo import DIMS
from protocols.messages import Message
from roger_daemon.tools.common import count, seconds
from simulator import transport
from simulator.sim_args import DAEMON_ENDPOINT, DEFAULT_LISTEN
from simulator.transport import StopFlag, Subscription

__all__ = ["NodeLoop", "PerceptionNode", "add_node_args", "hold"]

#: The counters every perception-driven node reports first, in this order.
PERCEPTION_COUNTS = ("perceptions", "commands", "resent", "stale_perceptions", "episodes")


def add_node_args(parser: argparse.ArgumentParser, *, predictions: bool = True,
                  who: str = "", idle_of: str = "perception") -> None:
    """The arguments every controller node shares, then the Zenoh ones.

    ``predictions`` adds ``--clock``, ``--prediction-timeout`` and ``--max-prediction-age``
    (the DPA, driven by predictions, has none); ``who`` prefixes their help (``"transitioner"``);
    ``idle_of`` names what ``--idle-exit`` waits for.
    """
    pre = f"{who}, " if who else ""
    parser.add_argument("--robot", default="aibo", help="robot id in the key expressions")
    if predictions:
        parser.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                            help=f"{who + ': ' if who else ''}how predictions are matched "
                                 "to perceptions")
        parser.add_argument("--prediction-timeout", type=seconds, default=2.0,
                            help=f"{pre}lockstep: seconds to wait for prediction(t)")
        parser.add_argument("--max-prediction-age", type=count, default=3,
                            help=f"{pre}realtime: newest prediction at most this many ticks old")
    parser.add_argument("--exit-when-done", action="store_true",
                        help="exit when the simulator's run is complete")
    parser.add_argument("--idle-exit", type=seconds, default=0.0,
                        help=f"exit after this many seconds without a {idle_of} (0: never)")
    parser.add_argument("--stats", default=None, help="write the exit counters (JSON) here")
    transport.add_zenoh_args(parser, listen=(transport.EPHEMERAL,),
                             connect=(DEFAULT_LISTEN, DAEMON_ENDPOINT))


def hold(x: np.ndarray) -> np.ndarray:
    """Stand still, head and tail where they are (the ``no_prediction`` command)."""
    y = np.zeros(DIMS.y)
    y[3:8] = np.asarray(x)[18:23]
    return y


class NodeLoop:
    """One session, one loop: every message of the driving inbox to :meth:`on_message`."""

    def __init__(self, args: argparse.Namespace, stop: StopFlag, role: str,
                 log: logging.Logger, name: str = "") -> None:
        self.args = args
        self.stop = stop
        self.role = role
        self.log = log
        self.robot = keys.validate_robot_id(args.robot)
        self.invalid = transport.InvalidCounter(name or role)
        self.counts: dict[str, int] = {}

    def loop(self, inbox: Subscription, events: Subscription,
             on_message: Callable[[Any], None], idle_of: str) -> None:
        """Serve ``inbox`` until stopped, idle or the simulator's run is complete."""
        last_seen = time.monotonic()
        done = False
        while not self.stop.stopped and not done:
            msg = transport.wait_for(inbox.poll, 0.1, self.stop)
            for ev in events.drain():
                assert isinstance(ev, EpisodeEvent)
                self.on_event(ev)
                if ev.event == "end" and ev.data.get("run_complete") and self.args.exit_when_done:
                    done = True
            if msg is None:
                if self.args.idle_exit > 0 and time.monotonic() - last_seen > self.args.idle_exit:
                    self.log.info("no %s for %.1f s; exiting", idle_of, self.args.idle_exit)
                    break
                continue
            last_seen = time.monotonic()
            on_message(msg)

    def on_event(self, ev: EpisodeEvent) -> None:
        """An episode event (none by default)."""

    def summary(self, **extra: Any) -> dict[str, Any]:
        """The exit counters: role, robot, the counts, ``extra``, the invalid messages."""
        return {"role": self.role, "robot": self.robot, **self.counts, **extra,
                "invalid_messages": self.invalid.total(),
                "invalid_by_reason": dict(self.invalid.counts)}


class PerceptionNode(NodeLoop):
    """perception(t) -> command(t): a repeated tick resent, ``t == 0`` a new episode."""

    def __init__(self, args: argparse.Namespace, stop: StopFlag, role: str,
                 log: logging.Logger, extra_counts: tuple[str, ...] = (),
                 name: str = "") -> None:
        super().__init__(args, stop, role, log, name)
        self.counts = dict.fromkeys((*PERCEPTION_COUNTS, *extra_counts), 0)
        self.last_tick = -1
        self.last_command: Command | None = None
        self._pred_cache: Prediction | None = None
        self.preds: Subscription | None = None

    def new_episode(self) -> None:
        """Perception with ``t == 0``: restart the node's state."""
        raise NotImplementedError

    def command_for(self, msg: Perception) -> Command:
        """The command of this (new) perception."""
        raise NotImplementedError

    def serve_perceptions(self, session: Any, *, predictions: bool) -> None:
        """Subscribe (``prediction`` too when ``predictions``), loop, close the inboxes."""
        self.perc = Subscription(session, self.robot, "perception", DIMS, self.invalid,
                                 capacity=256)
        self.events = Subscription(session, self.robot, "episode", None, self.invalid,
                                   capacity=256)
        if predictions:
            self.preds = Subscription(session, self.robot, "prediction", DIMS, self.invalid,
                                      capacity=64)
        self.pub_cmd = transport.publisher(session, keys.command(self.robot))
        self.loop(self.perc, self.events, self._on_message, "perception")
        for inbox in (self.perc, self.events, self.preds):
            if inbox is not None:
                inbox.close()

    def _on_message(self, msg: Message) -> None:
        assert isinstance(msg, Perception)
        self.counts["perceptions"] += 1
        new_episode = msg.t == 0.0 and msg.tick != self.last_tick
        if not new_episode and msg.tick == self.last_tick and self.last_command is not None:
            self.counts["resent"] += 1
            transport.put(self.pub_cmd, self.last_command)
            return
        if not new_episode and msg.tick < self.last_tick:
            self.counts["stale_perceptions"] += 1
            return
        if new_episode:
            self.new_episode()
            self.counts["episodes"] += 1
        self.last_tick = msg.tick
        cmd = self.command_for(msg)
        self.last_command = cmd
        transport.put(self.pub_cmd, cmd)
        self.counts["commands"] += 1

    def prediction_for(self, msg: Perception) -> Prediction | None:
        """prediction(t) by tick (lockstep, ``--prediction-timeout`` s at most), or the newest
        not older than ``--max-prediction-age`` ticks (realtime)."""
        preds = self.preds
        assert preds is not None
        lockstep = self.args.clock == "lockstep"

        def newest() -> Prediction | None:
            for m in preds.drain():
                assert isinstance(m, Prediction)
                # lockstep: only prediction(t) is kept, so that one of a higher tick (from
                # a daemon of another run on a reused port) cannot hide it for the rest of
                # the run (docs/testing.md, *Ports*)
                if lockstep:
                    if m.tick == msg.tick:
                        self._pred_cache = m
                elif self._pred_cache is None or m.tick >= self._pred_cache.tick:
                    self._pred_cache = m
            c = self._pred_cache
            if c is None:
                return None
            if lockstep:
                return c if c.tick == msg.tick else None
            return c if 0 <= msg.tick - c.tick <= self.args.max_prediction_age else None

        if lockstep:
            timeout = self.args.prediction_timeout
            got: Prediction | None = transport.wait_for(newest, timeout, self.stop)
            return got
        return newest()

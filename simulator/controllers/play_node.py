"""``roger play``: the robot plays alone, on ROGER's experts and their learned transitions.

No hand-coded controller runs: this node imports nothing of :mod:`simulator.controllers.hcc`
and reads no demonstrator label (docs/autonomy.md; ``tests/test_play_node.py`` checks both).
It loads the learned transitions of a ``roger+fsm`` model from a daemon checkpoint
(``--checkpoint FILE`` or the newest valid one of ``--robot`` in a checkpoint directory), and
for every perception(t) takes the daemon's ``prediction``(t) (the daemon in predict mode
serving that checkpoint; ``--prediction-timeout`` seconds at most, matched by tick; in
``--clock realtime`` the newest prediction not older than ``--max-prediction-age`` ticks) and
publishes as ``command``(t) the mean of the expert the learned transitions choose among the
prediction's multimap (:class:`roger_daemon.fsm.player.Player`), ``source =
"play:<expert>:<how>"`` with ``how``:

- ``learned``: the learned transitions chose (the robot's learned state is that expert);
- ``empty_multimap``: the model has no expert -> the prediction's own ``mean``;
- ``no_prediction``: nothing arrived in time -> a hold command (stand still, head and tail
  where they are, no motion), as ``roger hcc --role transitioner`` does.

It never publishes ``action``, so a daemon in any mode learns nothing from it. A perception
with ``t == 0`` starts a new episode (the learned state restarts); a repeated tick gets the
cached command again; with ``--exit-when-done`` it exits on the simulator's final ``end``
event. On exit it prints one JSON line of counters (also to ``--stats FILE``), with the ticks
spent in each learned state.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from protocols import Command, EpisodeEvent, Perception, Prediction, keys
from protocols.aibo import DIMS
from roger_daemon.fsm.player import Player, load_player
from roger_daemon.tools.common import count, seconds
from simulator.sim_args import DAEMON_ENDPOINT, DEFAULT_LISTEN
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

__all__ = ["PlayNode", "configure", "run"]

log = logging.getLogger("roger.play")


def configure(parser: argparse.ArgumentParser) -> None:
    """Command-line arguments of ``roger play``."""
    parser.add_argument("--checkpoint", type=Path, required=True, metavar="PATH",
                        help="a daemon checkpoint of a roger+fsm model, or a checkpoint "
                             "directory (its newest valid checkpoint of --robot)")
    parser.add_argument("--robot", default="aibo", help="robot id in the key expressions")
    parser.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                        help="how predictions are matched to perceptions")
    parser.add_argument("--prediction-timeout", type=seconds, default=2.0,
                        help="lockstep: seconds to wait for prediction(t)")
    parser.add_argument("--max-prediction-age", type=count, default=3,
                        help="realtime: newest prediction at most this many ticks old")
    parser.add_argument("--exit-when-done", action="store_true",
                        help="exit when the simulator's run is complete")
    parser.add_argument("--idle-exit", type=seconds, default=0.0,
                        help="exit after this many seconds without perception (0: never)")
    parser.add_argument("--stats", default=None, help="write the exit counters (JSON) here")
    add_zenoh_args(parser, listen=(EPHEMERAL,), connect=(DEFAULT_LISTEN, DAEMON_ENDPOINT))


def hold(x: np.ndarray) -> np.ndarray:
    """Stand still, head and tail where they are (the transitioner's ``no_prediction``)."""
    y = np.zeros(DIMS.y)
    y[3:8] = np.asarray(x)[18:23]
    return y


class PlayNode:
    """One session, one loop (the structure of ``roger hcc``'s node)."""

    def __init__(self, args: argparse.Namespace, player: Player, stop: StopFlag) -> None:
        self.args = args
        self.player = player
        self.stop = stop
        self.robot = keys.validate_robot_id(args.robot)
        self.invalid = InvalidCounter("play")
        self.counts: dict[str, int] = {"perceptions": 0, "commands": 0, "resent": 0,
                                       "stale_perceptions": 0, "episodes": 0,
                                       "no_prediction": 0}
        self.state_ticks: dict[str, int] = {}
        self.last_tick = -1
        self.last_command: Command | None = None
        self._pred_cache: Prediction | None = None

    def run(self, session: Any) -> dict[str, Any]:
        """Serve until stopped, idle or the simulator's run is complete; the counters."""
        self.perc = Subscription(session, self.robot, "perception", DIMS, self.invalid,
                                 capacity=256)
        self.events = Subscription(session, self.robot, "episode", None, self.invalid,
                                   capacity=256)
        self.preds = Subscription(session, self.robot, "prediction", DIMS, self.invalid,
                                  capacity=64)
        self.pub_cmd = publisher(session, keys.command(self.robot))
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
            inbox.close()
        return {"role": "play", "robot": self.robot, **self.counts, **self.player.counts,
                "state_ticks": self.state_ticks, "invalid_messages": self.invalid.total(),
                "invalid_by_reason": dict(self.invalid.counts)}

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
            self.player.reset()
            self.counts["episodes"] += 1
        self.last_tick = msg.tick
        x = np.asarray(msg.x)
        pred = self._prediction_for(msg)
        if pred is None:
            self.counts["no_prediction"] += 1
            y = hold(x)
            self.player.commit(y)
            source = "play:-1:no_prediction"
        else:
            y, how = self.player.command(x, pred.multimap, pred.mean)
            state = self.player.state if how == "learned" else pred.expert
            source = f"play:{state}:{how}"
            key = str(self.player.state)
            self.state_ticks[key] = self.state_ticks.get(key, 0) + 1
        cmd = Command(self.robot, msg.tick, msg.t, y=y, source=source)
        self.last_command = cmd
        put(self.pub_cmd, cmd)
        self.counts["commands"] += 1

    def _prediction_for(self, msg: Perception) -> Prediction | None:
        lockstep = self.args.clock == "lockstep"

        def newest() -> Prediction | None:
            for m in self.preds.drain():
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


def run(args: argparse.Namespace) -> int:
    """Load the learned transitions, then serve until stopped; print the counters."""
    try:
        player = load_player(args.checkpoint, args.robot)
    except (ValueError, OSError) as exc:
        print(f"roger play: {exc}", file=sys.stderr)
        return 2
    log.info("learned transitions from %s: %d states, %d transitions", args.checkpoint,
             len(player.fsm.transitions.sources()), len(player.fsm.transitions.pairs))
    serve(PlayNode(args, player, StopFlag()), args)
    return 0

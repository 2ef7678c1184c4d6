"""``roger experiment dpa``: the unimap baseline's controller (the paper's "DPA").

Direct policy approximation: whatever the learner predicts is what the robot does. This node
subscribes to the daemon's ``prediction`` (the daemon serves a ``model = "unimap"`` robot, one
sparse online GP on all the data) and publishes each prediction's ``mean`` as ``command`` of the
same tick, ``source = "dpa:<model>"``. There is no transitioner and no subtask: on a multimap
(one perception, several demonstrated actions) the single GP predicts near their average,
which is why the paper's DPA never scores.

In lockstep the simulator waits for command(t); the daemon answers perception(t) at once with
prediction(t), and a re-sent perception gets a second prediction of the same tick, which this
node forwards again (the simulator counts the duplicate as stale). With ``--exit-when-done``
the node exits on the simulator's final ``end`` event; it prints its counters as one JSON line
(also to ``--stats FILE``).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from typing import Any

import numpy as np

from protocols import Command, EpisodeEvent, Prediction, keys
from protocols.aibo import DIMS
from simulator.sim_node import DAEMON_ENDPOINT, DEFAULT_LISTEN
from simulator.transport import (
    EPHEMERAL,
    Inbox,
    InvalidCounter,
    StopFlag,
    add_zenoh_args,
    publisher,
    put,
    serve,
    wait_for,
)

__all__ = ["configure", "run"]

log = logging.getLogger("roger.dpa")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment dpa``."""
    parser.add_argument("--robot", default="aibo", help="robot id in the key expressions")
    parser.add_argument("--model", default="unimap", help="name in the command's source")
    parser.add_argument(
        "--exit-when-done", action="store_true", help="exit when the simulator's run is complete"
    )
    parser.add_argument(
        "--idle-exit",
        type=float,
        default=0.0,
        help="exit after this many seconds without a prediction (0: never)",
    )
    parser.add_argument("--stats", default=None, help="write the exit counters (JSON) here")
    add_zenoh_args(parser, listen=(EPHEMERAL,), connect=(DEFAULT_LISTEN, DAEMON_ENDPOINT))


class DPANode:
    """One session, one loop: prediction(t) -> command(t)."""

    def __init__(self, args: argparse.Namespace, stop: StopFlag) -> None:
        self.args = args
        self.stop = stop
        self.robot = keys.validate_robot_id(args.robot)
        self.invalid = InvalidCounter("dpa")
        self.counts = {"predictions": 0, "commands": 0, "repeated_ticks": 0, "episodes": 0}
        self.last_tick = -1

    def run(self, session: Any) -> dict[str, Any]:
        preds = Inbox(session, self.robot, "prediction", DIMS, self.invalid, capacity=256)
        events = Inbox(session, self.robot, "episode", None, self.invalid, capacity=256)
        pub = publisher(session, keys.command(self.robot))
        source = f"dpa:{self.args.model}"
        last_seen = time.monotonic()
        done = False
        while not self.stop.stopped and not done:
            msg = wait_for(preds.poll, 0.1, self.stop)
            for ev in events.drain():
                assert isinstance(ev, EpisodeEvent)
                if ev.event == "start":
                    self.counts["episodes"] += 1
                if ev.event == "end" and ev.data.get("run_complete") and self.args.exit_when_done:
                    done = True
            if msg is None:
                if self.args.idle_exit > 0 and time.monotonic() - last_seen > self.args.idle_exit:
                    log.info("no prediction for %.1f s; exiting", self.args.idle_exit)
                    break
                continue
            last_seen = time.monotonic()
            assert isinstance(msg, Prediction)
            self.counts["predictions"] += 1
            if msg.tick == self.last_tick:
                self.counts["repeated_ticks"] += 1
            self.last_tick = msg.tick
            put(pub, Command(self.robot, msg.tick, msg.t, y=np.asarray(msg.mean), source=source))
            self.counts["commands"] += 1
        preds.close()
        events.close()
        return {
            "role": "dpa",
            "robot": self.robot,
            **self.counts,
            "invalid_messages": self.invalid.total(),
            "invalid_by_reason": dict(self.invalid.counts),
        }


def run(args: argparse.Namespace) -> int:
    """Forward predictions as commands until stopped or the run is complete."""
    serve(DPANode(args, StopFlag()), args)
    return 0


if __name__ == "__main__":  # pragma: no cover - ``roger experiment dpa`` is the entry point
    logging.basicConfig(level=logging.INFO)
    p = argparse.ArgumentParser(prog="dpa")
    configure(p)
    sys.exit(run(p.parse_args()))

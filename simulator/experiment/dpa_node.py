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

With ``--trace FILE`` it also keeps, per tick, the perception and the command it sent, and
writes them at exit as one ``.npz`` (``tick``, ``t``, ``x``, ``y``; no pickled objects): the
experiment measures from it how much of each episode averaged the multimap
(:mod:`simulator.experiment.averaging`).
"""

from __future__ import annotations

import argparse
import io
import logging
import os
import sys
from typing import Any

import numpy as np

from protocols import Command, EpisodeEvent, Perception, Prediction, keys
from protocols.aibo import DIMS
from roger_daemon.atomic import write_bytes
from simulator.controllers.node import NodeLoop, add_node_args
from simulator.transport import StopFlag, Subscription, publisher, put, serve

__all__ = ["CommandTrace", "configure", "read_trace", "run"]

log = logging.getLogger("roger.dpa")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment dpa``."""
    parser.add_argument("--model", default="unimap", help="name in the command's source")
    parser.add_argument("--trace", default=None,
                        help="write each tick's perception and command (.npz) here at exit")
    add_node_args(parser, predictions=False, idle_of="prediction")


class DPANode(NodeLoop):
    """prediction(t) -> command(t), in the nodes' one loop (:mod:`simulator.controllers.node`)."""

    def __init__(self, args: argparse.Namespace, stop: StopFlag) -> None:
        super().__init__(args, stop, "dpa", log)
        self.counts = {"predictions": 0, "commands": 0, "repeated_ticks": 0, "episodes": 0}
        self.last_tick = -1
        self.trace = CommandTrace() if args.trace else None
        self.source = f"dpa:{args.model}"
        self.percs: Subscription | None = None

    def run(self, session: Any) -> dict[str, Any]:
        preds = Subscription(session, self.robot, "prediction", DIMS, self.invalid, capacity=256)
        events = Subscription(session, self.robot, "episode", None, self.invalid, capacity=256)
        if self.trace is not None:
            self.percs = Subscription(session, self.robot, "perception", DIMS, self.invalid,
                                      capacity=256)
        self.pub = publisher(session, keys.command(self.robot))
        self.loop(preds, events, self._on_prediction, "prediction")
        preds.close()
        events.close()
        if self.trace is not None and self.percs is not None:
            self.trace.perceptions(self.percs.drain())
            self.percs.close()
            self.trace.write(self.args.trace)
        return self.summary()

    def on_event(self, ev: EpisodeEvent) -> None:
        if ev.event == "start":
            self.counts["episodes"] += 1

    def _on_prediction(self, msg: Any) -> None:
        assert isinstance(msg, Prediction)
        self.counts["predictions"] += 1
        if msg.tick == self.last_tick:
            self.counts["repeated_ticks"] += 1
        self.last_tick = msg.tick
        y = np.asarray(msg.mean)
        put(self.pub, Command(self.robot, msg.tick, msg.t, y=y, source=self.source))
        self.counts["commands"] += 1
        if self.trace is not None and self.percs is not None:
            self.trace.perceptions(self.percs.drain())
            self.trace.command(msg.tick, y)


class CommandTrace:
    """Perception and command per tick (``--trace``); an episode starts at a perception with
    ``t == 0`` (the simulator's episode clock), as :mod:`simulator.controllers.hcc_node`
    detects it."""

    def __init__(self) -> None:
        self._x: dict[int, tuple[float, np.ndarray]] = {}
        self._y: dict[int, np.ndarray] = {}  # a re-sent tick: its last command

    def perceptions(self, msgs: list[Any]) -> None:
        """Perceptions received (a job's few episodes: kept whole, joined at :meth:`write`)."""
        for m in msgs:
            assert isinstance(m, Perception)
            self._x[m.tick] = (float(m.t), np.asarray(m.x, dtype=np.float64))

    def command(self, tick: int, y: np.ndarray) -> None:
        """The command sent for ``tick``."""
        self._y[tick] = np.asarray(y, dtype=np.float64)

    def write(self, path: str) -> None:
        """One ``.npz`` (``tick``, ``t``, ``x``, ``y``), written atomically."""
        ticks = np.array(sorted(set(self._x) & set(self._y)), dtype=np.int64)
        ts = np.array([self._x[int(k)][0] for k in ticks], dtype=np.float64)
        xs = np.array([self._x[int(k)][1] for k in ticks]).reshape(len(ticks), DIMS.x)
        ys = np.array([self._y[int(k)] for k in ticks]).reshape(len(ticks), DIMS.y)
        buf = io.BytesIO()
        np.savez(buf, tick=ticks, t=ts, x=xs, y=ys)
        write_bytes(path, buf.getvalue())


def read_trace(path: str | os.PathLike[str]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(x, y)`` per episode of a ``--trace`` file, in the order they ran."""
    with np.load(path, allow_pickle=False) as f:
        t, x, y = f["t"], f["x"], f["y"]
    starts = [int(i) for i in np.flatnonzero(t == 0.0)]
    bounds = [*starts, len(t)]
    return [(x[a:b], y[a:b]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def run(args: argparse.Namespace) -> int:
    """Forward predictions as commands until stopped or the run is complete."""
    serve(DPANode(args, StopFlag()), args)
    return 0


if __name__ == "__main__":  # pragma: no cover - ``roger experiment dpa`` is the entry point
    logging.basicConfig(level=logging.INFO)
    p = argparse.ArgumentParser(prog="dpa")
    configure(p)
    sys.exit(run(p.parse_args()))

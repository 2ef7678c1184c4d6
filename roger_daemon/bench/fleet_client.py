"""The client side of ``roger bench fleet`` and ``soak``: one Zenoh session playing N robots,
the feeder that publishes their streams, and the ``/proc`` readings of the daemon's CPU and
children (docs/fleet.md).

It is not a :class:`roger_daemon.client.RobotClient`: a RobotClient is one robot in a session of
its own, while the benchmark plays N robots on one session and one wildcard subscriber, and
stamps every prediction's raw bytes on arrival before decoding them (the latency it measures).
It publishes through RobotClient's own publisher rule (:func:`roger_daemon.client.robot_publisher`)
and encodes with :mod:`protocols`, so no rule of the robot side has a second copy here."""

from __future__ import annotations

import argparse
import os
import queue
import time
from typing import Any

import msgpack
import numpy as np

from protocols import Action, Perception, decode, encode, keys
from protocols.aibo import DIMS
from roger_daemon.bench.streams import FeedStream
from roger_daemon.machine import busy_cpu_s, cpu_time_split

__all__ = ["FleetClient", "child_pids", "feed", "index_predictions", "machine_window",
           "proc_cpu_s"]

#: a robot's predictions as received: (received, tick, published), monotonic ns of the
#: machine (the daemon's wall-clock ``stamp_ns`` moved onto the monotonic clock)
Received = list[tuple[int, int, int]]


def child_pids(pid: int) -> list[int]:
    """The ids of ``pid``'s child processes (from ``/proc``; empty where that is unreadable)."""
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children", encoding="ascii") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out


def proc_cpu_s(pid: int, *, children: bool = True) -> float:
    """CPU seconds (user + system) used so far by ``pid`` and its live child processes."""
    total = 0.0
    tick = os.sysconf("SC_CLK_TCK")
    for p in [pid, *(child_pids(pid) if children else [])]:
        try:
            with open(f"/proc/{p}/stat", encoding="ascii") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            continue
    return total


def machine_window(start: list[int] | None, end: list[int] | None, ours_s: float,
                   seconds: float) -> dict[str, float]:
    """What else ran on the machine over a measured window: ``other_cpu_percent``, the CPU
    its processes other than ours (``ours_s`` CPU seconds: the daemon, its workers and the
    bench's own processes) used, in % of one core, and ``steal_percent``, the share of the
    machine's CPU time the hypervisor stole. Both from :func:`roger_daemon.machine.cpu_times`
    readings at the window's ends (empty without them). ``/proc`` counts in clock ticks
    (10 ms), and with CPU stolen the processes' CPU times and ``/proc/stat``'s busy time do not
    count the stolen time alike (-2.5 to -3.0 % with 4-6 % stolen, docs/fleet.md): read
    ``other_cpu_percent`` within a few per cent of zero as zero.

    >>> machine_window([0] * 8, [300, 0, 100, 500, 0, 0, 0, 2], ours_s=3.5, seconds=5.0)
    {'other_cpu_percent': 10.0, 'steal_percent': 0.22}
    """
    if start is None or end is None or seconds <= 0:
        return {}
    split = cpu_time_split(start, end)
    if split is None:
        return {}
    other_s = busy_cpu_s(start, end) - ours_s
    return {"other_cpu_percent": round(100.0 * other_s / seconds, 2),
            "steal_percent": split["steal_percent"]}


def index_predictions(raw: list[tuple[int, str, bytes]], robots: list[str], wall_to_mono: int
                      ) -> tuple[dict[str, Received], int]:
    """Every received prediction validated and indexed by robot; and how many did not decode.

    ``raw`` holds (received monotonic ns, key, payload); ``wall_to_mono`` is the receiving
    process's ``time.time_ns() - time.monotonic_ns()``."""
    preds: dict[str, Received] = {r: [] for r in robots}
    errors = 0
    for now, key, payload in raw:
        try:
            robot, kind = keys.parse(key)
            msg = decode(kind, payload, dims=DIMS, robot=robot)
            preds[robot].append((now, msg.tick, msg.stamp_ns - wall_to_mono))
        except Exception:
            errors += 1
    return preds, errors


class FleetClient:
    """One Zenoh session playing every robot; collects status, and predictions unless another
    process receives them (``predictions=False``: ``roger bench fleet``'s realtime phase,
    :mod:`.fleet_receiver`)."""

    def __init__(self, connect: str, robots: list[str], *, predictions: bool = True) -> None:
        from roger_daemon.client import robot_publisher
        from roger_daemon.zenoh_session import ZenohSettings, open_session

        self.session = open_session(ZenohSettings(listen=(), connect=(connect,)))
        self.robots = robots
        self.sent: dict[str, dict[int, int]] = {r: {} for r in robots}
        self.preds: dict[str, Received] = {r: [] for r in robots}
        self._wall_to_mono = time.time_ns() - time.monotonic_ns()
        self.status: dict[str, list[tuple[int, Any]]] = {r: [] for r in robots}
        self.answered: queue.SimpleQueue[tuple[str, int]] = queue.SimpleQueue()
        self._raw: list[tuple[int, str, bytes]] = []  # (received, key, payload)
        self.errors = 0
        # a robot's own messages, published as RobotClient publishes them (never lost)
        self._pubs = {(r, k): robot_publisher(self.session, keys.key(r, k))
                      for r in robots for k in ("perception", "action")}
        self._subs = [self.session.declare_subscriber(keys.all_of_kind("status"),
                                                      self._on_status)]
        if predictions:
            self._subs.append(self.session.declare_subscriber(keys.all_of_kind("prediction"),
                                                              self._on_pred))
        self.lockstep = False

    def _decode(self, sample: Any) -> tuple[str, Any] | None:
        """(robot, message) of a sample, by the one key parser; ``None`` (counted) if bad."""
        try:
            robot, kind = keys.parse(str(sample.key_expr))
            return robot, decode(kind, sample.payload.to_bytes(), dims=DIMS, robot=robot)
        except Exception:
            self.errors += 1
            return None

    def _on_pred(self, sample: Any) -> None:
        # Keep the callback short: this one process receives every robot's predictions, and a
        # slow callback backs up Zenoh until the daemon's drop-on-congestion publisher drops
        # them. Predictions are validated after the phase (decode_predictions).
        now = time.monotonic_ns()
        payload = sample.payload.to_bytes()
        self._raw.append((now, str(sample.key_expr), payload))
        if self.lockstep:
            try:
                robot, _kind = keys.parse(str(sample.key_expr))
                tick = int(msgpack.unpackb(payload)["tick"])
            except Exception:
                return  # counted by decode_predictions
            self.answered.put((robot, tick))

    def decode_predictions(self) -> None:
        """Validate every prediction received (decode_errors) and index them by robot."""
        raw, self._raw = self._raw, []
        preds, errors = index_predictions(raw, self.robots, self._wall_to_mono)
        for robot, got in preds.items():
            self.preds[robot] += got
        self.errors += errors

    def _on_status(self, sample: Any) -> None:
        got = self._decode(sample)
        if got is not None:
            self.status[got[0]].append((time.monotonic_ns(), got[1]))

    def perception(self, robot: str, tick: int, x: np.ndarray) -> None:
        """Publish a perception for ``robot`` and note when it was sent."""
        self.sent[robot][tick] = time.monotonic_ns()
        self._pubs[(robot, "perception")].put(
            encode(Perception(robot, tick, tick / 30.0, x=x)))

    def action(self, robot: str, tick: int, y: np.ndarray, label: str) -> None:
        """Publish an action (the demonstrator's answer) for ``robot``."""
        self._pubs[(robot, "action")].put(
            encode(Action(robot, tick, tick / 30.0, y=y, label=label)))

    def last_status(self, before_ns: int) -> dict[str, Any]:
        """The last status of every robot received before ``before_ns``."""
        return {r: [m for t, m in self.status[r] if t < before_ns][-1] for r in self.robots}

    def wait_status(self, after_ns: int, timeout: float = 15.0) -> dict[str, Any]:
        """The first status of every robot received after ``after_ns``."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            got = {r: next((m for t, m in self.status[r] if t >= after_ns), None)
                   for r in self.robots}
            if all(m is not None for m in got.values()):
                return got
            time.sleep(0.05)
        raise TimeoutError("no status from every robot")

    def close(self) -> None:
        """Close the Zenoh session."""
        self.session.close()


def _stream_of(stream: FeedStream, i: int, n: int, tick: int
               ) -> tuple[np.ndarray, np.ndarray, str]:
    k = (tick + i * (len(stream.x) // max(n, 1))) % len(stream.x)
    return stream.x[k], stream.y[k], stream.labels[k]


def feed(fleet: FleetClient, stream: FeedStream, args: argparse.Namespace, lockstep: bool,
         stop_at: float, *, stagger: bool = False) -> int:
    """Publish at ``args.rate`` until ``stop_at``; in lockstep actions follow predictions.

    Every robot's perception of a tick is sent at the tick (the order rotating from tick to
    tick), or with ``stagger`` robot ``i`` of ``N`` sends ``i/N`` of a period after it, as
    robots with free-running clocks would."""
    n = len(fleet.robots)
    period = 1.0 / args.rate
    slot = period / n if stagger else 0.0
    t0 = time.monotonic()
    tick = 0
    while time.monotonic() < stop_at:
        for j in range(n):
            i = j if stagger else (tick + j) % n
            if stagger:
                _answer_until(fleet, stream, lockstep, t0 + tick * period + j * slot)
            r = fleet.robots[i]
            x, y, label = _stream_of(stream, i, n, tick)
            fleet.perception(r, tick, x)
            if not lockstep:
                fleet.action(r, tick, y, label)
        tick += 1
        _answer_until(fleet, stream, lockstep, t0 + tick * period)
    return tick


def _answer_until(fleet: FleetClient, stream: FeedStream, lockstep: bool,
                  deadline: float) -> None:
    """Wait until ``deadline`` (monotonic s); in lockstep answer predictions with actions."""
    n = len(fleet.robots)
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            return
        if not lockstep:
            time.sleep(left)
            return
        try:
            r, t = fleet.answered.get(timeout=left)
        except queue.Empty:
            return
        i = fleet.robots.index(r)
        _x, y, label = _stream_of(stream, i, n, t)
        fleet.action(r, t, y, label)

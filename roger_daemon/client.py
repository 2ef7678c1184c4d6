"""The robot's side of ROGER: send perceptions and actions, receive predictions.

:class:`RobotClient` is what a robot (or a simulator, a teleoperation rig, a test) runs to
talk to a ``roger daemon`` over Zenoh, so that nobody writes Zenoh and msgpack by hand from
``protocols/README.md``::

    from roger_daemon.client import RobotClient

    with RobotClient("tcp/127.0.0.1:7447", robot="arm", dims=(6, 2)) as robot:
        robot.wait_daemon()
        robot.send_action(0, y, label="reach")      # a demonstration: action(t) ...
        pred = robot.predict(0, x)                   # ... and perception(t); the answer
        pred.mean, pred.var                          # mean and variance per action entry
        [(e.expert, e.p, e.mean) for e in pred.multimap]   # every expert of the MAP particle

The daemon pairs perception(t) with action(t) by ``tick`` and learns each pair once
(``protocols/README.md``); it answers every perception (lockstep) or the newest one at its
rate (realtime) with a :class:`~protocols.Prediction`: the chosen expert's mean and variance,
``expert``, the ``multimap`` (each expert's gate probability, mean, variance, size, majority
label) and ``updates`` (pairs learned, durable). A perception without an action asks only for
a prediction. ``docs/your-robot.md`` walks through a robot of one's own;
``docs/examples/your_robot.py`` runs one against a real daemon.

Messages are published with congestion control BLOCK, so a robot never loses its own
messages on the way to a daemon that drains them (the daemon's outputs use DROP). Every
callback only decodes and appends under a lock; waiting happens in the caller's thread.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from protocols import Action, Control, Perception, Prediction, Status, decode, encode, keys
from protocols.messages import Dims
from roger_daemon.zenoh_session import DAEMON_ENDPOINT

__all__ = ["Received", "RobotClient", "checkpoint_outcome", "robot_publisher"]

FloatArray = npt.NDArray[np.float64]
_ACTION_FIELDS = {f.name for f in dataclasses.fields(Action)}


def checkpoint_outcome(before: Mapping[str, Any], now: Mapping[str, Any]) -> str | None:
    """Whether a checkpoint requested when the daemon's status ``info`` was ``before`` has
    ended by the status ``info`` ``now``: ``"written"`` once ``checkpoints_written`` grew,
    ``"failed"`` once ``checkpoint_errors`` grew, ``None`` while neither did
    (``protocols/README.md``, control). :meth:`RobotClient.checkpoint` and ``roger control``
    both decide by it."""
    def grew(key: str) -> bool:
        return int(now.get(key, 0)) > int(before.get(key, 0))

    if grew("checkpoint_errors"):
        return "failed"
    return "written" if grew("checkpoints_written") else None


def robot_publisher(session: Any, key: str) -> Any:
    """A publisher of a robot's own messages to the daemon (perception, action, control):
    congestion control BLOCK, priority ``REAL_TIME``, express (module docstring;
    ``docs/zenoh-notes.md`` §4.1). The one definition of that rule: :class:`RobotClient` and
    the fleet benchmark's client (one session playing many robots) both publish through it."""
    import zenoh

    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                     priority=zenoh.Priority.REAL_TIME, express=True)


@dataclass(frozen=True)
class Received:
    """A decoded message and the client's ``time.monotonic_ns()`` at receipt."""

    msg: Any
    recv_ns: int


class RobotClient:
    """One robot's connection to a ROGER daemon (module docstring). A context manager.

    Parameters
    ----------
    connect
        Zenoh endpoint(s) of the daemon or router, e.g. ``"tcp/127.0.0.1:7447"``.
    robot
        The robot id (the daemon's ``[[robots]] id``): keys ``roger/<robot>/...``.
    dims
        ``(perception size, action size)`` as the daemon is configured for this robot;
        incoming predictions are checked against it. Default: the AIBO's ``(23, 9)``;
        ``None``: not checked (an operator's tool that does not know the robot's sizes).
    rate_hz
        The robot's rate: a message's ``t`` is ``tick / rate_hz`` unless given.
    mode
        ``"peer"`` (default) or ``"client"`` (of a Zenoh router).
    daemon_id
        :meth:`wait_daemon` waits for this daemon's liveliness token; ``None``: any daemon.
    zenoh_config
        A Zenoh JSON5 file (authentication, TLS; ``configs/zenoh/secure/robot.json5``).
    session
        An open Zenoh session to use instead of opening one (``connect``, ``mode`` and
        ``zenoh_config`` are then unused); :meth:`close` leaves it open for its owner.
    """

    def __init__(self, connect: str | Sequence[str] = DAEMON_ENDPOINT, *,
                 robot: str = "aibo", dims: Dims | tuple[int, int] | None = (23, 9),
                 rate_hz: float = 30.0, mode: str = "peer", daemon_id: str | None = None,
                 zenoh_config: str | None = None, session: Any = None) -> None:
        import zenoh

        from roger_daemon.zenoh_session import ZenohSettings, open_session

        endpoints = (connect,) if isinstance(connect, str) else tuple(connect)
        self.robot = keys.validate_robot_id(robot)
        self.dims = dims if dims is None or isinstance(dims, Dims) else Dims(int(dims[0]),
                                                                              int(dims[1]))
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.rate_hz, self.daemon_id = float(rate_hz), daemon_id
        self._owns_session = session is None
        self.session = open_session(ZenohSettings(
            config_file=None if zenoh_config is None else Path(zenoh_config), mode=mode,
            connect=endpoints, listen=None if mode == "client" else ())
        ) if session is None else session
        #: every prediction / status received, in order (with receive times)
        self.predictions: list[Received] = []
        self.statuses: list[Received] = []
        #: payloads on this robot's keys that did not decode (a test asserts it stays empty)
        self.errors: list[str] = []
        self._cond = threading.Condition()
        self._closed = False
        self._subs = [self.session.declare_subscriber(keys.prediction(self.robot),
                                                      self._on("prediction")),
                      self.session.declare_subscriber(keys.status(self.robot),
                                                      self._on("status"))]
        self._cc = zenoh.CongestionControl.BLOCK  # send_raw to another robot: BLOCK too
        self._pubs = {kind: robot_publisher(self.session, keys.key(self.robot, kind))
                      for kind in ("perception", "action", "control")}

    # --- context manager ----------------------------------------------------------------------

    def __enter__(self) -> RobotClient:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Close the Zenoh session, or undeclare this client's subscribers and publishers on
        a session it was given (idempotent)."""
        if not self._closed:
            self._closed = True
            if self._owns_session:
                self.session.close()
                return
            for entity in (*self._subs, *self._pubs.values()):
                entity.undeclare()

    def _on(self, kind: str) -> Callable[[Any], None]:
        sink = self.predictions if kind == "prediction" else self.statuses

        def callback(sample: Any) -> None:
            now = time.monotonic_ns()
            try:
                msg = decode(kind, sample.payload.to_bytes(), dims=self.dims, robot=self.robot)
            except Exception as exc:  # a malformed message is counted, never raised here
                self.errors.append(f"{kind}: {exc}")
                return
            with self._cond:
                sink.append(Received(msg, now))
                self._cond.notify_all()

        return callback

    # --- sending ------------------------------------------------------------------------------

    def _t(self, tick: int, t: float | None) -> float:
        return tick / self.rate_hz if t is None else float(t)

    def send_raw(self, kind: str, payload: bytes, robot: str | None = None) -> None:
        """Publish an encoded payload of ``kind`` for this robot (or another ``robot``)."""
        if robot is None or robot == self.robot:
            self._pubs[kind].put(payload)
        else:
            self.session.put(keys.key(robot, kind), payload, congestion_control=self._cc)

    def send_perception(self, tick: int, x: Iterable[float] | FloatArray,
                        t: float | None = None) -> int:
        """Publish perception(``tick``); return the send time (``time.monotonic_ns``)."""
        sent = time.monotonic_ns()
        self.send_raw("perception", encode(Perception(self.robot, int(tick), self._t(tick, t),
                                                      x=np.asarray(x, dtype=np.float64))))
        return sent

    def send_action(self, tick: int, y: Iterable[float] | FloatArray, label: str = "",
                    t: float | None = None, source: str = "", correction: bool = False) -> None:
        """Publish the demonstrated action of ``tick`` (the training target for perception
        ``tick``), with its subtask ``label`` (kept as data, never learned from), who gave
        it, ``source`` (``"teacher"`` or ``"robot"``) and whether it is a teacher's
        ``correction`` of a robot that was driving (docs/teach.md)."""
        extra: dict[str, Any] = {}
        if source:
            if "source" not in _ACTION_FIELDS:
                raise ValueError("this protocol version's action message has no source field")
            extra["source"] = source
        if correction:
            extra["correction"] = True
        self.send_raw("action", encode(Action(self.robot, int(tick), self._t(tick, t),
                                              y=np.asarray(y, dtype=np.float64), label=label,
                                              **extra)))

    def send_control(self, op: str, mode: str = "") -> None:
        """Publish a control request: ``op`` ``"mode"`` (with ``mode``), ``"reset"`` or
        ``"checkpoint"``; :meth:`set_mode` and friends wait for the confirmation."""
        self.send_raw("control", encode(Control(self.robot, 0, 0.0, op=op, mode=mode)))

    def request(self, op: str, mode: str = "", timeout: float = 10.0) -> Status:
        """Send a control request (``op`` ``"mode"`` with ``mode``, ``"reset"`` or
        ``"checkpoint"``) and return the status that confirms it: the daemon's first status
        whose ``info["control_stamp_ns"]`` is the request's stamp, published once applied
        (``protocols/README.md``, control). ``TimeoutError`` after ``timeout`` seconds."""
        msg = Control(self.robot, 0, 0.0, op=op, mode=mode)
        with self._cond:
            seen = len(self.statuses)  # before sending: a quick confirmation is not missed
        self.send_raw("control", encode(msg))
        return self._wait_status_from(
            seen, lambda st: st.info.get("control_stamp_ns") == msg.stamp_ns, timeout)

    def set_mode(self, mode: str, timeout: float = 10.0) -> Status:
        """Switch the daemon's mode for this robot (``"learn"``, ``"predict"``,
        ``"learn+predict"``, ``"pause"``); return the status that confirms it."""
        return self.request("mode", mode, timeout)

    def reset(self, timeout: float = 10.0) -> Status:
        """Replace this robot's model by a fresh one; return the confirming status."""
        return self.request("reset", "", timeout)

    def checkpoint(self, timeout: float = 10.0) -> Status:
        """Ask for a checkpoint and wait until it is on disk; return that status, whose
        ``info["checkpoint"]`` names the file (``info["checkpoint_updates"]``: the pairs in
        it). The daemon confirms the request at once and writes the file in the background
        (``protocols/README.md``, control): the confirming status still names the previous
        checkpoint. ``RuntimeError`` if the daemon reports that the write failed,
        ``TimeoutError`` after ``timeout`` seconds in all."""
        end = time.monotonic() + timeout
        ack = self.request("checkpoint", "", timeout)
        return self.wait_checkpoint(ack, max(end - time.monotonic(), 0.0))

    def wait_checkpoint(self, ack: Status, timeout: float = 10.0) -> Status:
        """After the confirming status ``ack`` of a checkpoint request: the status that shows
        the file written (:func:`checkpoint_outcome`); ``RuntimeError`` if it shows the write
        failed, ``TimeoutError`` after ``timeout`` seconds."""
        done = self._wait_status_from(
            self._status_index(ack), lambda st: checkpoint_outcome(ack.info, st.info)
            is not None, timeout)
        if checkpoint_outcome(ack.info, done.info) == "failed":
            raise RuntimeError(f"the daemon reported that the checkpoint of {self.robot} "
                               f"failed (see its log)")
        return done

    def _status_index(self, st: Status) -> int:
        """How many statuses were received up to and including ``st`` (0 if not among them)."""
        with self._cond:
            return next((i + 1 for i in range(len(self.statuses) - 1, -1, -1)
                         if self.statuses[i].msg is st), 0)

    # --- receiving ----------------------------------------------------------------------------

    def wait_daemon(self, timeout: float = 60.0) -> None:
        """Wait until the daemon's liveliness token is visible (link and declarations up);
        ``TimeoutError`` after ``timeout`` seconds."""
        end = time.monotonic() + timeout
        key = (keys.daemon_liveliness(self.daemon_id) if self.daemon_id
               else keys.daemon_liveliness_all())
        while time.monotonic() < end:
            replies = self.session.liveliness().get(key, timeout=1.0)
            if any(r.ok is not None for r in replies):
                time.sleep(0.2)  # let our own subscriptions reach the daemon too
                return
            time.sleep(0.1)
        raise TimeoutError(f"no daemon token {key} within {timeout} s")

    def wait_received(self, tick: int, timeout: float = 60.0) -> Received:
        """The prediction of ``tick`` with its receive time (``TimeoutError`` after
        ``timeout`` seconds)."""
        end = time.monotonic() + timeout
        with self._cond:
            while True:
                for r in reversed(self.predictions):
                    if r.msg.tick == tick:
                        return r
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no prediction for tick {tick} within {timeout} s")
                self._cond.wait(left)

    def wait_prediction(self, tick: int, timeout: float = 60.0) -> Prediction:
        """The prediction of ``tick`` (``TimeoutError`` after ``timeout`` seconds)."""
        pred: Prediction = self.wait_received(tick, timeout).msg
        return pred

    def predict(self, tick: int, x: Iterable[float] | FloatArray, timeout: float = 10.0,
                t: float | None = None) -> Prediction:
        """Send perception(``tick``) and wait for its prediction."""
        self.send_perception(tick, x, t)
        return self.wait_prediction(tick, timeout)

    def trim_predictions(self, keep: int) -> None:
        """Forget all but the newest ``keep`` predictions (a long-running robot's memory)."""
        with self._cond:
            del self.predictions[:-keep or len(self.predictions)]

    def latest_prediction(self) -> Prediction | None:
        """The newest prediction received, if any."""
        with self._cond:
            return self.predictions[-1].msg if self.predictions else None

    def wait_status(self, predicate: Callable[[Status], bool] | None = None,
                    timeout: float = 60.0) -> Status:
        """The first status received from now on that satisfies ``predicate``."""
        with self._cond:
            seen = len(self.statuses)
        return self._wait_status_from(seen, predicate, timeout)

    def _wait_status_from(self, seen: int, predicate: Callable[[Status], bool] | None,
                          timeout: float) -> Status:
        """The first status after the ``seen`` first ones that satisfies ``predicate``."""
        end = time.monotonic() + timeout
        with self._cond:
            while True:
                for r in self.statuses[seen:]:
                    if predicate is None or predicate(r.msg):
                        st: Status = r.msg
                        return st
                seen = len(self.statuses)
                left = end - time.monotonic()
                if left <= 0:
                    last = self.statuses[-1].msg.to_map() if self.statuses else None
                    raise TimeoutError(f"no matching status within {timeout} s; last: {last}")
                self._cond.wait(left)

    def predictions_since(self, t_ns: int) -> list[Prediction]:
        """The predictions received at or after ``t_ns`` (``time.monotonic_ns``)."""
        with self._cond:
            return [r.msg for r in self.predictions if r.recv_ns >= t_ns]

"""The daemon's publications: per robot, predictions (real-time QoS) and status; each one is
recorded with the time it was published."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from protocols import keys
from protocols.messages import Message, encode
from roger_daemon.daemon.service.clock import Clock
from roger_daemon.daemon.service.recording import Recorders
from roger_daemon.transport import Publisher, Transport

__all__ = ["Outbox", "Publishers"]


@dataclass
class Publishers:
    """One robot's two publishers."""

    prediction: Publisher
    status: Publisher


class Outbox:
    """Encode, publish and record the daemon's messages."""

    def __init__(self, recorders: Recorders, clock: Clock) -> None:
        self.recorders = recorders
        self.clock = clock
        self.pubs: dict[str, Publishers] = {}

    def declare(self, transport: Transport, robots: Iterable[str]) -> None:
        """Declare the publishers of ``robots`` (once, at start)."""
        for robot in robots:
            self.pubs[robot] = Publishers(
                transport.publisher(keys.prediction(robot), realtime=True),
                transport.publisher(keys.status(robot), realtime=False),
            )

    def prediction(self, robot: str, payload: bytes, stamp_ns: int, tick: int) -> None:
        """Publish and record a prediction of ``robot``, encoded by
        ``RobotRuntime.answer`` and stamped with ``protocols.messages.stamp_prediction``."""
        self.pubs[robot].prediction.put(payload)
        self.recorders.write(robot, keys.prediction(robot), payload, self.clock.time_ns(),
                             stamp_ns, tick)

    def status(self, robot: str, msg: Message) -> None:
        """Publish and record a status of ``robot``."""
        self._publish(robot, self.pubs[robot].status, keys.status(robot), msg)

    def _publish(self, robot: str, pub: Publisher, key: str, msg: Message) -> None:
        payload = encode(msg)
        pub.put(payload)
        self.recorders.write(robot, key, payload, self.clock.time_ns(), msg.stamp_ns, msg.tick)

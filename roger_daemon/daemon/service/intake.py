"""Which inbox items reach the loop: key, served robot, size and decoding checked; every
rejection counted by reason (on the robot, or as unserved when no served robot is to blame).

Admitted messages of the served robots, rejected ones included, are recorded as they are taken
off the inbox (the log's order is the order the daemon handled them in).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping

from protocols import keys
from protocols.errors import ProtocolError
from protocols.messages import MAX_PAYLOAD_BYTES, Message, decode
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.service.recording import Recorders
from roger_daemon.transport import Incoming

__all__ = ["INPUT_KINDS", "RECORD_ONLY_KINDS", "Admission"]

log = logging.getLogger(__name__)

INPUT_KINDS = ("perception", "action", "control")
RECORD_ONLY_KINDS = ("command", "episode")


class Admission:
    """Checks and decodes inbox items for the served ``robots``; counts what it rejects.

    ``count_unserved``: count messages for robots that are not served (``[daemon]``).
    """

    def __init__(self, robots: Mapping[str, RobotRuntime], recorders: Recorders, *,
                 count_unserved: bool) -> None:
        self.robots = robots
        self.recorders = recorders
        self.count_unserved = count_unserved
        #: rejections no served robot can be blamed for (bad keys, unserved robots)
        self.unserved: Counter[str] = Counter()
        self._reported: set[str] = set()

    def admit(self, item: Incoming) -> tuple[RobotRuntime, str, Message] | None:
        """The robot, kind and decoded message of ``item``; ``None`` when it goes no further."""
        parts = item.key.split("/")
        robot = parts[1] if len(parts) == 3 else ""
        rt = self.robots.get(robot)
        try:
            served_robot, kind = keys.parse(item.key)
        except ProtocolError as exc:
            if rt is not None or self.count_unserved:
                self.invalid(rt, exc.reason, exc.detail)
            return None
        if rt is None:
            if kind in INPUT_KINDS and self.count_unserved:
                self.invalid(None, "unknown_robot",
                             f"message on {item.key}: robot {served_robot!r} is not served")
            return None
        if kind not in INPUT_KINDS and kind not in RECORD_ONLY_KINDS:
            return None  # predictions and status: daemons' outputs (ours included), not decoded
        if item.payload is None:
            self.invalid(rt, "oversized",
                         f"{kind}: payload of {item.size} bytes > {MAX_PAYLOAD_BYTES}")
            return None
        try:
            msg = decode(kind, item.payload, dims=rt.dims, robot=robot)
        except ProtocolError as exc:  # garbage on command/episode is counted too
            self.invalid(rt, exc.reason, exc.detail)
            self.recorders.write(robot, item.key, item.payload, item.recv_wall_ns,
                                 item.recv_wall_ns, 0)
            return None
        self.recorders.write(robot, item.key, item.payload, item.recv_wall_ns, msg.stamp_ns,
                             msg.tick)
        return rt, kind, msg

    def invalid(self, rt: RobotRuntime | None, reason: str, detail: str) -> None:
        """Count one rejected message on ``rt`` (or as unserved); log the first of a reason."""
        if rt is not None:
            rt.count_invalid(reason, detail)
            return
        self.unserved[reason] += 1
        if reason not in self._reported:
            self._reported.add(reason)
            log.warning("rejected message (%s); further ones are only counted", detail)

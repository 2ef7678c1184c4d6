"""Key expressions, built here and nowhere else.

Every robot has seven keys ``roger/<robot>/<kind>``; daemons also declare a liveliness token
``roger/@daemon/<daemon-id>``. The daemon's decision records (``protocols.decisions``) are
log channels ``roger/<robot>/daemon/<event>``, never published. For a hot standby the daemon
serving a robot publishes its ``learned``, ``reset`` and ``dropped`` records on
``roger/@daemon/<daemon-id>/replica/<robot>/<event>`` and holds the liveliness token
``roger/@daemon/<daemon-id>/active/<robot>/<epoch>`` (docs/daemon.md, *Hot standby*): a
verbatim ``@daemon`` chunk is matched by no wildcard, so ``roger/**`` (recorders, the daemon's
own intake) never sees them.
"""

from __future__ import annotations

import re

from protocols.errors import ProtocolError

__all__ = [
    "DECISIONS",
    "KINDS",
    "ROBOT_ID_PATTERN",
    "ROOT",
    "action",
    "active_token",
    "active_tokens",
    "all_of_kind",
    "command",
    "control",
    "daemon_liveliness",
    "decision",
    "daemon_liveliness_all",
    "episode",
    "everything",
    "key",
    "parse",
    "parse_active",
    "parse_decision",
    "parse_replica",
    "parse_sync",
    "perception",
    "prediction",
    "replica",
    "replicas",
    "status",
    "sync",
    "validate_robot_id",
]

ROOT = "roger"
KINDS = ("perception", "action", "command", "prediction", "episode", "status", "control")
#: the daemon's decision records (session-log channels only)
DECISIONS = ("learned", "reset", "dropped", "model")
#: a robot (or daemon) id: 1-64 of ``[A-Za-z0-9_-]`` (also the schemas' ``robot`` pattern)
ROBOT_ID_PATTERN = r"^[A-Za-z0-9_\-]{1,64}$"
_ID = re.compile(ROBOT_ID_PATTERN)


def validate_robot_id(robot: str) -> str:
    """Return ``robot`` if it is a valid id (1-64 of ``[A-Za-z0-9_-]``), else raise."""
    if not isinstance(robot, str) or not _ID.match(robot):
        raise ProtocolError(
            "bad_value", f"robot id must be 1-64 characters of [A-Za-z0-9_-], got {robot!r}"
        )
    return robot


def key(robot: str, kind: str) -> str:
    """``roger/<robot>/<kind>`` for one of :data:`KINDS`."""
    if kind not in KINDS:
        raise ProtocolError("bad_key", f"kind must be one of {KINDS}, got {kind!r}")
    return f"{ROOT}/{validate_robot_id(robot)}/{kind}"


def perception(robot: str) -> str:
    """Perception published by the robot or simulator."""
    return key(robot, "perception")


def action(robot: str) -> str:
    """Demonstrator action (with subtask label), the learner's training target."""
    return key(robot, "action")


def command(robot: str) -> str:
    """Command executed by the robot or simulator."""
    return key(robot, "command")


def prediction(robot: str) -> str:
    """Learner prediction (mean, variance, multimap)."""
    return key(robot, "prediction")


def episode(robot: str) -> str:
    """Episode events from the simulator."""
    return key(robot, "episode")


def status(robot: str) -> str:
    """Daemon status for one robot, 1 Hz."""
    return key(robot, "status")


def control(robot: str) -> str:
    """Control requests to the daemon (mode, reset, checkpoint)."""
    return key(robot, "control")


def all_of_kind(kind: str) -> str:
    """``roger/*/<kind>``: one kind for every robot."""
    if kind not in KINDS:
        raise ProtocolError("bad_key", f"kind must be one of {KINDS}, got {kind!r}")
    return f"{ROOT}/*/{kind}"


def everything() -> str:
    """``roger/**``: every ROGER message (what a recorder subscribes to)."""
    return f"{ROOT}/**"


def daemon_liveliness(daemon_id: str) -> str:
    """Liveliness token of one daemon."""
    return f"{ROOT}/@daemon/{validate_robot_id(daemon_id)}"


def daemon_liveliness_all() -> str:
    """Liveliness key expression matching every daemon."""
    return f"{ROOT}/@daemon/*"


def active_token(daemon_id: str, robot: str, epoch: int) -> str:
    """Liveliness token of the daemon serving ``robot`` (a hot standby watches it); ``epoch``
    counts the takeovers that led to this daemon serving it."""
    if not isinstance(epoch, int) or epoch < 0:
        raise ProtocolError("bad_value", f"epoch must be an integer >= 0, got {epoch!r}")
    return (f"{ROOT}/@daemon/{validate_robot_id(daemon_id)}/active/{validate_robot_id(robot)}"
            f"/{epoch}")


def active_tokens(robot: str = "*") -> str:
    """Key expression of every daemon's active token for ``robot`` (``"*"``: any robot)."""
    if robot != "*":
        validate_robot_id(robot)
    return f"{ROOT}/@daemon/*/active/{robot}/*"


def parse_active(key_expr: str) -> tuple[str, str, int] | None:
    """``(daemon, robot, epoch)`` of an active token's key, or ``None`` if it is not one."""
    parts = str(key_expr).split("/")
    if (len(parts) != 6 or parts[0] != ROOT or parts[1] != "@daemon" or parts[3] != "active"
            or not _ID.match(parts[2]) or not _ID.match(parts[4]) or not parts[5].isdigit()):
        return None
    return parts[2], parts[4], int(parts[5])


def replica(daemon_id: str, robot: str, event: str) -> str:
    """Where the daemon serving ``robot`` publishes its decision records of ``event``."""
    if event not in DECISIONS:
        raise ProtocolError("bad_key", f"event must be one of {DECISIONS}, got {event!r}")
    daemon_id, robot = validate_robot_id(daemon_id), validate_robot_id(robot)
    return f"{ROOT}/@daemon/{daemon_id}/replica/{robot}/{event}"


def replicas(robot: str) -> str:
    """Key expression of every daemon's published decision records for ``robot``."""
    return f"{ROOT}/@daemon/*/replica/{validate_robot_id(robot)}/*"


def sync(daemon_id: str, robot: str) -> str:
    """Where the daemon ``daemon_id`` answers a standby's catch-up query for ``robot``."""
    daemon_id, robot = validate_robot_id(daemon_id), validate_robot_id(robot)
    return f"{ROOT}/@daemon/{daemon_id}/sync/{robot}"


def parse_sync(key_expr: str) -> tuple[str, str] | None:
    """``(daemon, robot)`` of a catch-up answer's key, or ``None``."""
    parts = str(key_expr).split("/")
    if (len(parts) != 5 or parts[0] != ROOT or parts[1] != "@daemon" or parts[3] != "sync"
            or not _ID.match(parts[2]) or not _ID.match(parts[4])):
        return None
    return parts[2], parts[4]


def parse_replica(key_expr: str) -> tuple[str, str, str] | None:
    """``(daemon, robot, event)`` of a published decision record's key, or ``None``."""
    parts = str(key_expr).split("/")
    if (len(parts) != 6 or parts[0] != ROOT or parts[1] != "@daemon" or parts[3] != "replica"
            or not _ID.match(parts[2]) or not _ID.match(parts[4]) or parts[5] not in DECISIONS):
        return None
    return parts[2], parts[4], parts[5]


def parse(key_expr: str) -> tuple[str, str]:
    """Split ``roger/<robot>/<kind>`` into ``(robot, kind)``; raise ``ProtocolError`` otherwise."""
    parts = str(key_expr).split("/")
    if len(parts) != 3 or parts[0] != ROOT or parts[2] not in KINDS or not _ID.match(parts[1]):
        raise ProtocolError("bad_key", f"expected roger/<robot>/<kind>, got {key_expr!r}")
    return parts[1], parts[2]


def decision(robot: str, event: str) -> str:
    """``roger/<robot>/daemon/<event>``: the log channel of one kind of decision record."""
    if event not in DECISIONS:
        raise ProtocolError("bad_key", f"event must be one of {DECISIONS}, got {event!r}")
    return f"{ROOT}/{validate_robot_id(robot)}/daemon/{event}"


def parse_decision(key_expr: str) -> tuple[str, str] | None:
    """``(robot, event)`` of a decision channel, or ``None`` if ``key_expr`` is not one."""
    parts = str(key_expr).split("/")
    if (len(parts) != 4 or parts[0] != ROOT or parts[2] != "daemon"
            or parts[3] not in DECISIONS or not _ID.match(parts[1])):
        return None
    return parts[1], parts[3]

"""The daemon's validated configuration: immutable dataclasses and :class:`ConfigError`.

Built by :func:`roger_daemon.config.load_config` (see :mod:`roger_daemon.config`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocols.aibo import DIMS as AIBO_DIMS
from roger_daemon.zenoh_session import ZenohSettings

__all__ = [
    "CLOCKS",
    "DEFAULT_PRESET",
    "DEFAULT_PROFILE",
    "FSM_MODEL",
    "WORKERS",
    "ZENOH_MODES",
    "CheckpointConfig",
    "ConfigError",
    "DaemonConfig",
    "RecordingConfig",
    "ROLES",
    "RobotConfig",
    "ZenohSettings",
]

CLOCKS = ("realtime", "lockstep")
WORKERS = ("auto", "process", "inline")
#: ``[daemon] role``: serve the robots, or follow the serving daemon as a hot standby
ROLES = ("primary", "standby")
#: ROGER with its transitions learned online (roger_daemon/fsm/online.py, docs/autonomy.md)
FSM_MODEL = "roger+fsm"
#: the profile of a robot that names none (if its dimensions are that profile's)
DEFAULT_PROFILE = "aibo"
DEFAULT_PRESET = "default"
ZENOH_MODES = ("peer", "client")


class ConfigError(ValueError):
    """A configuration value that is missing, unknown or out of range.

    ``str(err)`` is the whole message, starting with ``config error:``; ``key`` is the dotted
    TOML key (``""`` for file-level problems).
    """

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"config error: {message}")
        self.key = key

@dataclass(frozen=True)
class RobotConfig:
    """One robot served by the daemon, with its own model."""

    id: str
    x_dim: int = AIBO_DIMS.x
    y_dim: int = AIBO_DIMS.y
    model: str = "roger"
    seed: int = 0
    #: the robot profile's reference as configured: a shipped name (``"aibo"``: documented
    #: ranges -> [-1, 1], tail inputs dropped), a path to a profile file, or ``"none"``
    profile: str = "none"
    #: The learner parameters for this robot: ``[learner]`` merged with the robot's scaling.
    params: Any = None
    #: the loaded profile (names, ranges; ``roger_daemon.profiles``), ``None`` for ``"none"``
    robot_profile: Any = None


@dataclass(frozen=True)
class CheckpointConfig:
    """Where and how often models are saved (0 disables a trigger)."""

    dir: Path = Path("runs/checkpoints")
    every_updates: int = 1000
    every_s: float = 60.0
    keep: int = 5
    on_shutdown: bool = True
    shutdown_learn_s: float = 1.0
    #: write-ahead log of learned pairs (roger_daemon.daemon.wal); committed before every
    #: prediction/status that reports them, and at least every ``wal_commit_ms``
    wal: bool = True
    wal_commit_ms: float = 50.0
    #: the log's zero-filled reserve ahead of its records (kB, in [64, 65536]); on a full
    #: disk learning stops below a quarter of it (docs/durability.md, *Disk full*)
    wal_reserve_kb: int = 1024
    #: retention: delete the oldest checkpoints beyond these (0: no limit); ``keep`` still
    #: bounds the count and the newest checkpoint is never deleted
    max_bytes: int = 0
    max_age_days: float = 0.0

    def limits(self) -> dict[str, Any]:
        """Retention arguments of :func:`roger_daemon.daemon.checkpoint.write_checkpoint`."""
        return {"keep": self.keep, "max_bytes": self.max_bytes,
                "max_age_s": self.max_age_days * 86400.0}


@dataclass(frozen=True)
class RecordingConfig:
    """The in-daemon session recorder (``roger_daemon.recording``)."""

    enabled: bool = True
    dir: Path = Path("runs/recordings")
    #: retention of finished session files per robot (0: no limit); checked at start-up and
    #: on every rotation; the session being written is never deleted
    max_bytes: int = 0
    max_age_days: float = 0.0


@dataclass(frozen=True)
class DaemonConfig:
    """Everything the daemon needs, validated. Build it with :func:`load_config`."""

    id: str = "roger"
    clock: str = "realtime"
    rate_hz: float = 30.0
    status_hz: float = 1.0
    mode: str = "learn+predict"
    queue_size: int = 256
    pair_window: int = 64
    seed: int = 0
    count_unserved: bool = True
    #: "process": the robots' models in worker processes (roger_daemon.daemon.learners);
    #: "inline": every model in the service loop's thread; "auto": inline for one robot (lower
    #: latency), processes for several (learning on every core); docs/fleet.md
    workers: str = "auto"
    #: learner workers run this much nicer than the loop (0..19), so the loop and Zenoh's
    #: threads (and the robots' own processes on this machine) get a core before learning
    #: does: realtime ticks publish on time, lockstep answers reach the robot sooner
    #: (docs/fleet.md, *Scheduling and fairness*)
    worker_nice: int = 5
    #: worker processes serving the robots' models (with ``workers = "process"``): 0 is one
    #: per usable core, at most one per robot; each serves several robots' models in turn
    #: (docs/fleet.md, *A pool of workers*)
    worker_processes: int = 0
    #: "primary": serve the robots; "standby": follow the serving daemon's decisions and take
    #: its robots over when its liveliness token goes (docs/daemon.md, *Hot standby*)
    role: str = "primary"
    log_dir: Path | None = None
    robots: tuple[RobotConfig, ...] = ()
    learner: Mapping[str, Any] = field(default_factory=dict)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)

    @property
    def learner_workers(self) -> str:
        """Where models learn: ``workers`` with ``"auto"`` resolved by the number of robots
        (measured: one robot answers faster inline, several learn more in processes)."""
        if self.workers != "auto":
            return self.workers
        return "process" if len(self.robots) > 1 else "inline"

    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    source: Path | None = None

    def robot(self, robot_id: str) -> RobotConfig:
        """The config of one served robot (KeyError if not served)."""
        for r in self.robots:
            if r.id == robot_id:
                return r
        raise KeyError(robot_id)

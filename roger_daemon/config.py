"""The daemon's configuration: one TOML file, validated once into an immutable object.

Layering (style anchor 11): the TOML file (``configs/roger.toml``), then ``--set KEY=VALUE``
overrides from the command line, then validation. Every rejection raises :class:`ConfigError`
whose message names the key, the expected form and the value given, e.g.::

    config error: daemon.rate_hz must be a number > 0, got "fast"

Relative paths are taken relative to the current working directory (systemd:
``WorkingDirectory=``). The learner table is validated by
:meth:`roger_daemon.learner.RogerParams.from_mapping`; its errors are re-raised naming the
TOML key ``learner.<name>``.

``learner.preset`` names a row of :data:`roger_daemon.learner.params.PRESETS` (``"default"``
unless given; ``"paper"`` is the paper's literal numbers with every lever off); the other
``[learner]`` keys override it.  Each robot's ``profile`` sets its input/output scaling and
input weights: ``"aibo"`` (the default for a 23-D/9-D robot unless the preset is ``"paper"``)
maps every documented sensor and command range of ``protocols/AIBO.md`` onto [-1, 1] and drops
the state-free tail inputs; ``"none"`` leaves the data as it is.  A robot's own ``x_offset``,
``x_scale``, ``y_offset``, ``y_scale`` and ``input_weights`` override its profile's.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from protocols.aibo import DIMS as AIBO_DIMS
from protocols.keys import validate_robot_id
from protocols.messages import MODES

__all__ = [
    "CLOCKS",
    "WORKERS",
    "MODELS",
    "PROFILES",
    "CheckpointConfig",
    "ConfigError",
    "DaemonConfig",
    "RecordingConfig",
    "RobotConfig",
    "ZenohSettings",
    "apply_overrides",
    "load_config",
    "parse_config",
]

CLOCKS = ("realtime", "lockstep")
WORKERS = ("auto", "process", "inline")
MODELS = ("roger", "unimap")
PROFILES = ("aibo", "none")
DEFAULT_PRESET = "default"
ZENOH_MODES = ("peer", "client")
_ID_FORM = "a string of 1-64 characters [A-Za-z0-9_-]"
_MISSING = object()


class ConfigError(ValueError):
    """A configuration value that is missing, unknown or out of range.

    ``str(err)`` is the whole message, starting with ``config error:``; ``key`` is the dotted
    TOML key (``""`` for file-level problems).
    """

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"config error: {message}")
        self.key = key


def _show(value: Any) -> str:
    """A value as the user wrote it in TOML (strings quoted)."""
    try:
        return json.dumps(value)
    except (TypeError, ValueError):
        return repr(value)


def _bad(key: str, expected: str, value: Any) -> ConfigError:
    return ConfigError(key, f"{key} must be {expected}, got {_show(value)}")


# --- the immutable result -----------------------------------------------------------------


@dataclass(frozen=True)
class RobotConfig:
    """One robot served by the daemon, with its own model."""

    id: str
    x_dim: int = AIBO_DIMS.x
    y_dim: int = AIBO_DIMS.y
    model: str = "roger"
    seed: int = 0
    #: ``"aibo"`` (documented ranges -> [-1, 1], tail inputs dropped) or ``"none"``.
    profile: str = "none"
    #: The learner parameters for this robot: ``[learner]`` merged with the robot's scaling.
    params: Any = None


@dataclass(frozen=True)
class ZenohSettings:
    """How the daemon joins Zenoh. ``None`` means "leave to the JSON5 file or Zenoh's default"."""

    config_file: Path | None = None
    mode: str | None = "peer"
    listen: tuple[str, ...] | None = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] | None = ()
    multicast_scouting: bool | None = False
    lease_ms: int | None = None


@dataclass(frozen=True)
class CheckpointConfig:
    """Where and how often models are saved (0 disables a trigger)."""

    dir: Path = Path("runs/checkpoints")
    every_updates: int = 1000
    every_s: float = 60.0
    keep: int = 5
    on_shutdown: bool = True
    shutdown_learn_s: float = 1.0
    #: write-ahead log of learned pairs (roger_daemon.wal); committed before every
    #: prediction/status that reports them, and at least every ``wal_commit_ms``
    wal: bool = True
    wal_commit_ms: float = 50.0
    #: retention: delete the oldest checkpoints beyond these (0: no limit); ``keep`` still
    #: bounds the count and the newest checkpoint is never deleted
    max_bytes: int = 0
    max_age_days: float = 0.0

    def limits(self) -> dict[str, Any]:
        """Retention arguments of :func:`roger_daemon.checkpoint.write_checkpoint`."""
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
    #: "process": each robot's model in its own worker process (roger_daemon.learners);
    #: "inline": every model in the service loop's thread; "auto": inline for one robot (lower
    #: latency), processes for several (learning on every core); docs/fleet.md
    workers: str = "auto"
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


# --- typed readers ---------------------------------------------------------------------------


class _Table:
    """A TOML table being consumed: every key read is ticked off; leftovers are unknown keys."""

    def __init__(self, data: Any, prefix: str) -> None:
        if not isinstance(data, dict):
            raise _bad(prefix or "(top level)", "a table", data)
        self.data: dict[str, Any] = data
        self.prefix = prefix
        self.seen: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        self.seen.add(name)
        if name in self.data:
            return self.data[name]
        if default is _MISSING:
            raise ConfigError(self.key(name), f"{self.key(name)} is required")
        return default

    def number(self, name: str, default: float, *, lo: float = 0.0, lo_open: bool = True) -> float:
        v = self.raw(name, default)
        op = ">" if lo_open else ">="
        want = f"a number {op} {lo:g}"
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise _bad(self.key(name), want, v)
        if (v <= lo) if lo_open else (v < lo):
            raise _bad(self.key(name), want, v)
        return float(v)

    def integer(self, name: str, default: int, *, lo: int = 0) -> int:
        v = self.raw(name, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise _bad(self.key(name), f"an integer >= {lo}", v)
        return v

    def boolean(self, name: str, default: bool) -> bool:
        v = self.raw(name, default)
        if not isinstance(v, bool):
            raise _bad(self.key(name), "true or false", v)
        return v

    def choice(self, name: str, default: str, choices: Sequence[str]) -> str:
        v = self.raw(name, default)
        if v not in choices:
            raise _bad(self.key(name), "one of " + ", ".join(_show(c) for c in choices), v)
        return str(v)

    def string(self, name: str, default: Any = _MISSING) -> str:
        v = self.raw(name, default)
        if not isinstance(v, str) or not v:
            raise _bad(self.key(name), "a non-empty string", v)
        return v

    def ident(self, name: str, default: Any = _MISSING) -> str:
        v = self.raw(name, default)
        try:
            return validate_robot_id(v)
        except Exception:
            raise _bad(self.key(name), _ID_FORM, v) from None

    def path(self, name: str, default: Path | None) -> Path | None:
        v = self.raw(name, default)
        if v is None or isinstance(v, Path):
            return v
        if not isinstance(v, str):
            raise _bad(self.key(name), "a path (string)", v)
        return Path(v) if v else None

    def strings(self, name: str, default: tuple[str, ...] | None) -> tuple[str, ...] | None:
        v = self.raw(name, default)
        if v is None or isinstance(v, tuple):
            return v
        if not isinstance(v, list) or not all(isinstance(e, str) and e for e in v):
            raise _bad(self.key(name), "an array of strings", v)
        return tuple(v)

    def floats(self, name: str, length: int) -> tuple[float, ...] | None:
        v = self.raw(name, None)
        if v is None:
            return None
        want = f"an array of {length} finite numbers"
        if (
            not isinstance(v, list)
            or len(v) != length
            or not all(
                isinstance(e, int | float) and not isinstance(e, bool) and math.isfinite(e)
                for e in v
            )
        ):
            raise _bad(self.key(name), want, v)
        return tuple(float(e) for e in v)

    def sub(self, name: str) -> _Table:
        return _Table(self.raw(name, {}), self.key(name))

    def done(self) -> None:
        unknown = sorted(set(self.data) - self.seen)
        if unknown:
            k = self.key(unknown[0])
            known = ", ".join(sorted(self.seen))
            raise ConfigError(k, f"unknown key {k} (known keys here: {known})")


# --- parsing -----------------------------------------------------------------------------


_PARAM_NAME = re.compile(r"^([a-z_][a-z0-9_]*) ")


def _learner_error(exc: Exception, prefix: str) -> ConfigError:
    """Turn a learner ``ParameterError`` into a config error naming the TOML key."""
    text = str(exc)
    m = _PARAM_NAME.match(text)
    if m and not text.startswith("unknown"):
        return ConfigError(f"{prefix}.{m.group(1)}", f"{prefix}.{text}")
    return ConfigError(prefix, f"{prefix}: {text}")


def _learner_mapping(learner_table: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """``(preset name, RogerParams mapping)``: the preset's row, then the table's own keys."""
    from roger_daemon.learner.params import PRESETS

    table = dict(learner_table)
    preset = table.pop("preset", DEFAULT_PRESET)
    if not isinstance(preset, str) or preset not in PRESETS:
        raise _bad("learner.preset", "one of " + ", ".join(_show(c) for c in PRESETS), preset)
    return preset, {**PRESETS[preset], **table}


def _profile_mapping(profile: str, x_dim: int, y_dim: int, key: str) -> dict[str, Any]:
    """The scaling and input weights of a robot profile (``"aibo"``: ``protocols/AIBO.md``)."""
    if profile == "none":
        return {}
    from protocols.aibo import ACTION_RANGES, PERCEPTION_RANGES, STATE_FREE_DIMS, range_scaling

    if (x_dim, y_dim) != (AIBO_DIMS.x, AIBO_DIMS.y):
        raise _bad(key, f'"none" for a robot whose dimensions are not the AIBO\'s '
                   f"({AIBO_DIMS.x}, {AIBO_DIMS.y}); x_dim, y_dim = {x_dim}, {y_dim}", profile)
    x_offset, x_scale = range_scaling(PERCEPTION_RANGES)
    y_offset, y_scale = range_scaling(ACTION_RANGES)
    weights = [0.0 if i in STATE_FREE_DIMS else 1.0 for i in range(x_dim)]
    return {"x_offset": list(x_offset), "x_scale": list(x_scale), "y_offset": list(y_offset),
            "y_scale": list(y_scale), "input_weights": weights}


def _robot_params(
    learner_table: Mapping[str, Any], robot: _Table, x_dim: int, y_dim: int, idx: str
) -> tuple[str, Any]:
    from roger_daemon.learner import ParameterError, RogerParams

    preset, mapping = _learner_mapping(learner_table)
    aibo = (x_dim, y_dim) == (AIBO_DIMS.x, AIBO_DIMS.y) and preset != "paper"
    profile = robot.choice("profile", "aibo" if aibo else "none", PROFILES)
    mapping.update(_profile_mapping(profile, x_dim, y_dim, robot.key("profile")))
    scaling_keys: dict[str, str] = {}
    for name, length in (("x_offset", x_dim), ("x_scale", x_dim),
                         ("y_offset", y_dim), ("y_scale", y_dim), ("input_weights", x_dim)):
        vec = robot.floats(name, length)
        if vec is not None:
            if name.endswith("scale") and any(e <= 0 for e in vec):
                raise _bad(robot.key(name), f"an array of {length} numbers > 0", list(vec))
            if name == "input_weights" and (min(vec) < 0 or max(vec) <= 0):
                raise _bad(robot.key(name), f"an array of {length} numbers >= 0, not all 0",
                           list(vec))
            mapping[name] = list(vec)
            scaling_keys[name] = robot.key(name)
    try:
        params = RogerParams.from_mapping(mapping)
    except ParameterError as exc:
        raise _learner_error(exc, "learner") from None
    try:
        params.check_dims(x_dim, y_dim)
    except ParameterError as exc:
        m = _PARAM_NAME.match(str(exc))
        name = m.group(1) if m else ""
        if name in scaling_keys:
            raise ConfigError(scaling_keys[name], f"{idx}.{exc}") from None
        raise _learner_error(exc, "learner") from None
    return profile, params


def _check_zenoh_file(path: Path) -> None:
    import zenoh

    try:
        zenoh.Config.from_file(str(path))
    except Exception as exc:  # zenoh raises ZError for unreadable or invalid files
        raise ConfigError(
            "zenoh.config_file",
            f"zenoh.config_file must be a readable Zenoh JSON5 config, got {_show(str(path))} "
            f"({exc})",
        ) from None


def parse_config(data: Mapping[str, Any], *, source: Path | None = None) -> DaemonConfig:
    """Validate a parsed TOML document into a :class:`DaemonConfig`."""
    top = _Table(dict(data), "")
    d = top.sub("daemon")
    cfg_id = d.ident("id", "roger")
    clock = d.choice("clock", "realtime", CLOCKS)
    rate_hz = d.number("rate_hz", 30.0)
    if rate_hz > 1000:
        raise _bad("daemon.rate_hz", "a number > 0 and <= 1000", rate_hz)
    status_hz = d.number("status_hz", 1.0)
    if status_hz > 100:
        raise _bad("daemon.status_hz", "a number > 0 and <= 100", status_hz)
    mode = d.choice("mode", "learn+predict", MODES)
    queue_size = d.integer("queue_size", 256, lo=1)
    pair_window = d.integer("pair_window", 64, lo=1)
    seed = d.integer("seed", 0, lo=0)
    count_unserved = d.boolean("count_unserved", True)
    workers = d.choice("workers", "auto", WORKERS)
    log_dir = d.path("log_dir", None)
    d.done()

    learner_raw = top.raw("learner", {})
    if not isinstance(learner_raw, dict):
        raise _bad("learner", "a table", learner_raw)
    learner_table = dict(learner_raw)

    robots_raw = top.raw("robots", [{"id": "aibo"}])
    if not isinstance(robots_raw, list) or not robots_raw:
        raise _bad("robots", "a non-empty array of tables ([[robots]])", robots_raw)
    robots: list[RobotConfig] = []
    for i, raw in enumerate(robots_raw):
        r = _Table(raw, f"robots[{i}]")
        rid = r.ident("id")
        if any(o.id == rid for o in robots):
            raise _bad(r.key("id"), "unique among robots", rid)
        x_dim = r.integer("x_dim", AIBO_DIMS.x, lo=1)
        y_dim = r.integer("y_dim", AIBO_DIMS.y, lo=1)
        model = r.choice("model", "roger", MODELS)
        rseed = r.integer("seed", seed, lo=0)
        profile, params = _robot_params(learner_table, r, x_dim, y_dim, f"robots[{i}]")
        r.done()
        robots.append(RobotConfig(rid, x_dim, y_dim, model, rseed, profile, params))

    z = top.sub("zenoh")
    zfile = z.path("config_file", None)
    zdefault = ZenohSettings() if zfile is None else ZenohSettings(None, None, None, None, None)
    zmode = z.raw("mode", zdefault.mode)
    if zmode is not None and zmode not in ZENOH_MODES:
        raise _bad("zenoh.mode", 'one of "peer", "client"', zmode)
    listen_default = None if zmode == "client" else zdefault.listen
    listen = z.strings("listen", listen_default)
    connect = z.strings("connect", zdefault.connect)
    mcast = z.raw("multicast_scouting", zdefault.multicast_scouting)
    if mcast is not None and not isinstance(mcast, bool):
        raise _bad("zenoh.multicast_scouting", "true or false", mcast)
    lease = z.raw("lease_ms", None)
    if lease is not None and (isinstance(lease, bool) or not isinstance(lease, int) or lease < 100):
        raise _bad("zenoh.lease_ms", "an integer >= 100 (milliseconds)", lease)
    z.done()
    for ep_key, eps in (("zenoh.listen", listen), ("zenoh.connect", connect)):
        for ep in eps or ():
            if "/" not in ep:
                raise _bad(ep_key, 'an array of endpoints like "tcp/127.0.0.1:7447"',
                           list(eps or ()))
    if zmode == "client" and not connect and zfile is None:
        raise _bad("zenoh.connect", "at least one endpoint when zenoh.mode is \"client\"", [])
    if zfile is not None:
        _check_zenoh_file(zfile)
    zenoh_settings = ZenohSettings(zfile, zmode, listen, connect, mcast, lease)

    c = top.sub("checkpoint")
    ckpt = CheckpointConfig(
        dir=c.path("dir", CheckpointConfig.dir) or CheckpointConfig.dir,
        every_updates=c.integer("every_updates", CheckpointConfig.every_updates, lo=0),
        every_s=c.number("every_s", CheckpointConfig.every_s, lo=0.0, lo_open=False),
        keep=c.integer("keep", CheckpointConfig.keep, lo=1),
        on_shutdown=c.boolean("on_shutdown", True),
        shutdown_learn_s=c.number("shutdown_learn_s", 1.0, lo=0.0, lo_open=False),
        wal=c.boolean("wal", True),
        wal_commit_ms=c.number("wal_commit_ms", 50.0),
        max_bytes=c.integer("max_bytes", 0, lo=0),
        max_age_days=c.number("max_age_days", 0.0, lo=0.0, lo_open=False),
    )
    if ckpt.wal_commit_ms > 50.0:
        raise _bad("checkpoint.wal_commit_ms", "a number in (0, 50] (milliseconds)",
                   ckpt.wal_commit_ms)
    if ckpt.shutdown_learn_s > 3.0:
        raise _bad("checkpoint.shutdown_learn_s", "a number in [0, 3] (seconds)",
                   ckpt.shutdown_learn_s)
    c.done()

    rec = top.sub("recording")
    recording = RecordingConfig(
        enabled=rec.boolean("enabled", True),
        dir=rec.path("dir", RecordingConfig.dir) or RecordingConfig.dir,
        max_bytes=rec.integer("max_bytes", 0, lo=0),
        max_age_days=rec.number("max_age_days", 0.0, lo=0.0, lo_open=False),
    )
    rec.done()
    top.done()

    return DaemonConfig(
        id=cfg_id, clock=clock, rate_hz=rate_hz, status_hz=status_hz, mode=mode,
        queue_size=queue_size, pair_window=pair_window, seed=seed,
        count_unserved=count_unserved, workers=workers, log_dir=log_dir, robots=tuple(robots),
        learner=MappingProxyType(dict(learner_table)), zenoh=zenoh_settings, checkpoint=ckpt,
        recording=recording, source=source,
    )


def apply_overrides(data: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Apply ``SECTION.KEY=VALUE`` overrides (VALUE in TOML syntax; bare words are strings)."""
    out: dict[str, Any] = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    for item in overrides:
        if "=" not in item:
            raise ConfigError("", f"override {item!r} must look like SECTION.KEY=VALUE")
        dotted, text = item.split("=", 1)
        parts = dotted.strip().split(".")
        if len(parts) != 2 or not all(parts):
            raise ConfigError(
                dotted, f"override key {dotted!r} must be SECTION.KEY (e.g. daemon.clock)"
            )
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        section = out.setdefault(parts[0], {})
        if not isinstance(section, dict):
            raise ConfigError(dotted, f"cannot override {dotted}: {parts[0]} is not a table")
        section[parts[1]] = value
    return out


def load_config(path: str | Path | None, overrides: Sequence[str] = ()) -> DaemonConfig:
    """Read, override and validate. ``path=None`` means all defaults (robot ``aibo``)."""
    data: dict[str, Any] = {}
    source = None
    if path is not None:
        source = Path(path)
        try:
            text = source.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError("", f"cannot read {source}: {exc.strerror or exc}") from None
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError("", f"{source} is not valid TOML: {exc}") from None
    return parse_config(apply_overrides(data, overrides), source=source)

"""Parse and validate the daemon's TOML document into a :class:`DaemonConfig`.

One function per section (``[daemon]``, ``[learner]`` with ``[[robots]]``, ``[zenoh]``,
``[checkpoint]``, ``[recording]``); layering and error form in :mod:`roger_daemon.config`.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

from protocols.aibo import DIMS as AIBO_DIMS
from protocols.messages import MODES, Dims
from roger_daemon.config.settings import (
    CLOCKS,
    DEFAULT_PRESET,
    DEFAULT_PROFILE,
    FSM_MODEL,
    ROLES,
    WORKERS,
    ZENOH_MODES,
    CheckpointConfig,
    ConfigError,
    DaemonConfig,
    RecordingConfig,
    RobotConfig,
    ZenohSettings,
)
from roger_daemon.config.table import Table, bad, show
from roger_daemon.profiles import ProfileError, RobotProfile, load_profile, shipped_profiles

__all__ = ["apply_overrides", "daemon_settings", "load_config", "parse_config", "robot_config"]


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
        raise bad("learner.preset", "one of " + ", ".join(show(c) for c in PRESETS), preset)
    return preset, {**PRESETS[preset], **table}


def _robot_profile(robot: Table, preset: str) -> tuple[str, RobotProfile | None, Dims]:
    """``(profile reference, profile, dims)`` of a ``[[robots]]`` table.

    ``profile`` is a shipped profile's name (``configs/robots/<name>.toml``), a path to a
    profile file, or ``"none"``. Without it a robot gets :data:`DEFAULT_PROFILE` if its
    dimensions are that profile's and the preset is not ``"paper"`` (the AIBO's, as always).
    ``x_dim``/``y_dim`` default to the profile's (the default profile's without one).
    """
    spec = robot.raw("profile", None)
    if spec is not None and (not isinstance(spec, str) or not spec):
        raise bad(robot.key("profile"), '"none", a shipped profile (' + ", ".join(
            show(n) for n in shipped_profiles()) + ") or a path to a profile .toml file", spec)
    try:
        profile = load_profile(spec if spec not in (None, "none") else DEFAULT_PROFILE)
    except ProfileError as exc:
        raise ConfigError(robot.key("profile"), f"{robot.key('profile')}: {exc}") from None
    dims = Dims(robot.integer("x_dim", profile.dims.x, lo=1),
                robot.integer("y_dim", profile.dims.y, lo=1))
    if spec is None:
        keep = dims == profile.dims and preset != "paper"
        return (DEFAULT_PROFILE if keep else "none"), (profile if keep else None), dims
    if spec == "none":
        return "none", None, dims
    if dims != profile.dims:
        raise bad(robot.key("profile"), f'"none" or a profile of {dims.x} perception and '
                  f"{dims.y} action names for a robot with x_dim, y_dim = {dims.x}, {dims.y} "
                  f"(profile {profile.name!r} has {profile.dims.x}, {profile.dims.y})", spec)
    return spec, profile, dims


def _declared_ranges(robot: Table, dims: Dims) -> dict[str, Any]:
    """The scaling of a robot's own ``x_ranges`` / ``y_ranges`` (``[[low, high], ...]``)."""
    from roger_daemon.learner.params import ParameterError, range_scaling

    out: dict[str, Any] = {}
    for axis, n in (("x", dims.x), ("y", dims.y)):
        name = f"{axis}_ranges"
        value = robot.raw(name, None)
        if value is None:
            continue
        expected = f"an array of {n} [low, high] pairs of numbers with high > low"
        if not isinstance(value, list) or len(value) != n:
            raise bad(robot.key(name), expected, value)
        try:
            offset, scale = range_scaling(value, name)
        except ParameterError:
            raise bad(robot.key(name), expected, value) from None
        out[f"{axis}_offset"], out[f"{axis}_scale"] = list(offset), list(scale)
    return out


def _robot_params(
    learner_table: Mapping[str, Any], robot: Table, idx: str
) -> tuple[str, RobotProfile | None, Dims, Any]:
    from roger_daemon.learner import ParameterError, RogerParams

    preset, mapping = _learner_mapping(learner_table)
    spec, profile, dims = _robot_profile(robot, preset)
    x_dim, y_dim = dims.x, dims.y
    if profile is not None:
        mapping.update(profile.scaling())
    mapping.update(_declared_ranges(robot, dims))
    scaling_keys: dict[str, str] = {}
    for name, length in (("x_offset", x_dim), ("x_scale", x_dim),
                         ("y_offset", y_dim), ("y_scale", y_dim), ("input_weights", x_dim)):
        vec = robot.floats(name, length)
        if vec is not None:
            if name.endswith("scale") and any(e <= 0 for e in vec):
                raise bad(robot.key(name), f"an array of {length} numbers > 0", list(vec))
            if name == "input_weights" and (min(vec) < 0 or max(vec) <= 0):
                raise bad(robot.key(name), f"an array of {length} numbers >= 0, not all 0",
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
    # nu0 = x_dim + 1 unless set: the value the models use, recorded as such (metadata,
    # checkpoints), so that a config and the model it made agree (24 for the AIBO's 23)
    return spec, profile, dims, params.for_dims(x_dim)


def _check_zenoh_file(path: Path) -> None:
    import zenoh

    try:
        zenoh.Config.from_file(str(path))
    except Exception as exc:  # zenoh raises ZError for unreadable or invalid files
        raise ConfigError(
            "zenoh.config_file",
            f"zenoh.config_file must be a readable Zenoh JSON5 config, got {show(str(path))} "
            f"({exc})",
        ) from None


def parse_config(data: Mapping[str, Any], *, source: Path | None = None) -> DaemonConfig:
    """Validate a parsed TOML document into a :class:`DaemonConfig`."""
    top = Table(dict(data), "")
    daemon = _daemon_section(top.sub("daemon"))
    learner_raw = top.raw("learner", {})
    if not isinstance(learner_raw, dict):
        raise bad("learner", "a table", learner_raw)
    learner_table = dict(learner_raw)
    robots = _robots(top, learner_table, daemon["seed"])
    zenoh_settings = _zenoh_section(top.sub("zenoh"))
    ckpt = _checkpoint_section(top.sub("checkpoint"))
    recording = _recording_section(top.sub("recording"))
    top.done()
    return DaemonConfig(
        **daemon, robots=tuple(robots), learner=MappingProxyType(dict(learner_table)),
        zenoh=zenoh_settings, checkpoint=ckpt, recording=recording, source=source,
    )


def _daemon_section(d: Table) -> dict[str, Any]:
    """The ``[daemon]`` table as :class:`DaemonConfig` keyword arguments (the defaults are
    :class:`DaemonConfig`'s, written there once)."""
    c = DaemonConfig
    out: dict[str, Any] = {"id": d.ident("id", c.id), "clock": d.choice("clock", c.clock, CLOCKS)}
    out["rate_hz"] = rate_hz = d.number("rate_hz", c.rate_hz)
    if rate_hz > 1000:
        raise bad("daemon.rate_hz", "a number > 0 and <= 1000", rate_hz)
    out["status_hz"] = status_hz = d.number("status_hz", c.status_hz)
    if status_hz > 100:
        raise bad("daemon.status_hz", "a number > 0 and <= 100", status_hz)
    out.update(
        mode=d.choice("mode", c.mode, MODES),
        queue_size=d.integer("queue_size", c.queue_size, lo=1),
        pair_window=d.integer("pair_window", c.pair_window, lo=1),
        seed=d.integer("seed", c.seed, lo=0),
        count_unserved=d.boolean("count_unserved", c.count_unserved),
        workers=d.choice("workers", c.workers, WORKERS),
        worker_nice=d.integer("worker_nice", c.worker_nice, lo=0),
        worker_processes=d.integer("worker_processes", c.worker_processes, lo=0),
        role=d.choice("role", c.role, ROLES),
        log_dir=d.path("log_dir", c.log_dir),
    )
    if out["worker_nice"] > 19:
        raise bad("daemon.worker_nice", "an integer from 0 to 19", out["worker_nice"])
    d.done()
    return out


def _robots(top: Table, learner_table: Mapping[str, Any], seed: int) -> list[RobotConfig]:
    """The ``[[robots]]`` array (ids unique; each robot's learner parameters resolved)."""
    robots_raw = top.raw("robots", [{"id": "aibo"}])
    if not isinstance(robots_raw, list) or not robots_raw:
        raise bad("robots", "a non-empty array of tables ([[robots]])", robots_raw)
    robots: list[RobotConfig] = []
    for i, raw in enumerate(robots_raw):
        r = Table(raw, f"robots[{i}]")
        rid = r.ident("id")
        if any(o.id == rid for o in robots):
            raise bad(r.key("id"), "unique among robots", rid)
        from roger_daemon.config.models import MODELS

        model = r.choice("model", RobotConfig.model, tuple(MODELS))
        rseed = r.integer("seed", seed, lo=0)  # [daemon] seed unless the robot names one
        spec, profile, dims, params = _robot_params(learner_table, r, f"robots[{i}]")
        r.done()
        if model == FSM_MODEL and (dims.x, dims.y) != (AIBO_DIMS.x, AIBO_DIMS.y):
            raise bad(r.key("model"), f"a robot of the AIBO's dimensions for {FSM_MODEL!r} "
                      "(the only memory layout shipped, docs/autonomy.md)", model)
        robots.append(RobotConfig(rid, dims.x, dims.y, model, rseed, spec, params,
                                  robot_profile=profile))
    return robots


def robot_config(cfg: DaemonConfig, robot_id: str, dims: Dims) -> RobotConfig:
    """The robot ``robot_id`` of ``cfg``; a robot it does not list is resolved as the daemon
    would resolve ``[[robots]] id = robot_id, x_dim, y_dim = dims`` added to it (its
    ``[learner]`` table, ``[daemon] seed``, the default profile where the dims are its)."""
    try:
        return cfg.robot(robot_id)
    except KeyError:
        pass
    r = Table({"id": robot_id, "x_dim": dims.x, "y_dim": dims.y}, "robots[-]")
    spec, profile, got, params = _robot_params(cfg.learner, r, "robots[-]")
    return RobotConfig(robot_id, got.x, got.y, RobotConfig.model, cfg.seed, spec, params,
                       robot_profile=profile)


def daemon_settings(text: str) -> dict[str, Any]:
    """The ``[daemon]`` settings of a config's text (a recorded session's ``config``), each
    validated and defaulted as :func:`load_config` does, the file's other sections not read
    (a recorded config may name files this machine lacks). Raises :class:`ConfigError`."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("", f"not valid TOML: {exc}") from None
    return _daemon_section(Table(data, "").sub("daemon"))


def _zenoh_section(z: Table) -> ZenohSettings:
    """The ``[zenoh]`` table (with a ``config_file``, unset keys are left to the file)."""
    zfile = z.path("config_file", None)
    zdefault = ZenohSettings() if zfile is None else ZenohSettings(None, None, None, None, None,
                                                                   realtime_queue=None)
    zmode = z.raw("mode", zdefault.mode)
    if zmode is not None and zmode not in ZENOH_MODES:
        raise bad("zenoh.mode", 'one of "peer", "client"', zmode)
    listen_default = None if zmode == "client" else zdefault.listen
    listen = z.strings("listen", listen_default)
    connect = z.strings("connect", zdefault.connect)
    mcast = z.raw("multicast_scouting", zdefault.multicast_scouting)
    if mcast is not None and not isinstance(mcast, bool):
        raise bad("zenoh.multicast_scouting", "true or false", mcast)
    lease = z.raw("lease_ms", None)
    if lease is not None and (isinstance(lease, bool) or not isinstance(lease, int) or lease < 100):
        raise bad("zenoh.lease_ms", "an integer >= 100 (milliseconds)", lease)
    z.done()
    for ep_key, eps in (("zenoh.listen", listen), ("zenoh.connect", connect)):
        for ep in eps or ():
            if "/" not in ep:
                raise bad(ep_key, 'an array of endpoints like "tcp/127.0.0.1:7447"',
                          list(eps or ()))
    if zmode == "client" and not connect and zfile is None:
        raise bad("zenoh.connect", "at least one endpoint when zenoh.mode is \"client\"", [])
    if zfile is not None:
        _check_zenoh_file(zfile)
    return ZenohSettings(zfile, zmode, listen, connect, mcast, lease,
                         realtime_queue=zdefault.realtime_queue)


def _checkpoint_section(c: Table) -> CheckpointConfig:
    """The ``[checkpoint]`` table."""
    d = CheckpointConfig  # its defaults, written there once
    ckpt = CheckpointConfig(
        # absolute (from the working directory at start): status, `roger control checkpoint`
        # and the logs name files any reader can open (issue 56)
        dir=c.directory("dir", d.dir).absolute(),
        every_updates=c.integer("every_updates", d.every_updates, lo=0),
        every_s=c.number("every_s", d.every_s, lo=0.0, lo_open=False),
        keep=c.integer("keep", d.keep, lo=1),
        on_shutdown=c.boolean("on_shutdown", d.on_shutdown),
        shutdown_learn_s=c.number("shutdown_learn_s", d.shutdown_learn_s, lo=0.0,
                                  lo_open=False),
        wal=c.boolean("wal", d.wal),
        wal_commit_ms=c.number("wal_commit_ms", d.wal_commit_ms),
        wal_reserve_kb=c.integer("wal_reserve_kb", d.wal_reserve_kb, lo=64),
        max_bytes=c.integer("max_bytes", d.max_bytes, lo=0),
        max_age_days=c.number("max_age_days", d.max_age_days, lo=0.0, lo_open=False),
    )
    if ckpt.wal_commit_ms > 50.0:
        raise bad("checkpoint.wal_commit_ms", "a number in (0, 50] (milliseconds)",
                  ckpt.wal_commit_ms)
    if ckpt.wal_reserve_kb > 65536:
        raise bad("checkpoint.wal_reserve_kb", "an integer in [64, 65536] (kB)",
                  ckpt.wal_reserve_kb)
    if ckpt.shutdown_learn_s > 3.0:
        raise bad("checkpoint.shutdown_learn_s", "a number in [0, 3] (seconds)",
                  ckpt.shutdown_learn_s)
    c.done()
    return ckpt


def _recording_section(rec: Table) -> RecordingConfig:
    """The ``[recording]`` table."""
    d = RecordingConfig  # its defaults, written there once
    recording = RecordingConfig(
        enabled=rec.boolean("enabled", d.enabled),
        dir=rec.directory("dir", d.dir).absolute(),
        max_bytes=rec.integer("max_bytes", d.max_bytes, lo=0),
        max_age_days=rec.number("max_age_days", d.max_age_days, lo=0.0, lo_open=False),
    )
    rec.done()
    return recording


def apply_overrides(data: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Apply ``SECTION.KEY=VALUE`` overrides (VALUE in TOML syntax; bare words are strings).
    ``robots.KEY=VALUE`` sets KEY in every ``[[robots]]`` table (the default robot's if none)."""
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
        if parts[0] == "robots":
            robots = out.get("robots", [{"id": "aibo"}])
            if not isinstance(robots, list) or not all(isinstance(r, dict) for r in robots):
                raise ConfigError(dotted, f"cannot override {dotted}: robots is not an array "
                                  "of tables")
            out["robots"] = [{**r, parts[1]: value} for r in robots]
            continue
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

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
``[learner]`` keys override it.  Each robot's ``profile`` (:mod:`roger_daemon.profiles`: a
shipped name, a path to a profile file, or ``"none"``) names its dimensions and sets its
input/output scaling and input weights: ``"aibo"`` (``configs/robots/aibo.toml``; the default
for a 23-D/9-D robot unless the preset is ``"paper"``) maps every documented sensor and command
range of ``protocols/AIBO.md`` onto [-1, 1] and drops the state-free tail inputs; ``"none"``
leaves the data as it is.  A robot's own ``x_ranges`` / ``y_ranges`` (declared ranges, mapped
onto [-1, 1]), then ``x_offset``, ``x_scale``, ``y_offset``, ``y_scale`` and ``input_weights``
override its profile's.
"""

from __future__ import annotations

from roger_daemon.config.parse import (
    apply_overrides,
    daemon_settings,
    load_config,
    parse_config,
    robot_config,
)
from roger_daemon.config.settings import (
    CLOCKS,
    DEFAULT_PROFILE,
    WORKERS,
    CheckpointConfig,
    ConfigError,
    DaemonConfig,
    RecordingConfig,
    RobotConfig,
    ZenohSettings,
)

__all__ = [
    "CLOCKS",
    "WORKERS",
    "DEFAULT_PROFILE",
    "CheckpointConfig",
    "ConfigError",
    "DaemonConfig",
    "RecordingConfig",
    "RobotConfig",
    "ZenohSettings",
    "apply_overrides",
    "daemon_settings",
    "load_config",
    "parse_config",
    "robot_config",
]

"""Robot profiles as data: a robot's dimension names, declared ranges and ignored inputs.

A profile is a small TOML file (``configs/robots/<name>.toml``, shipped in the package; or any
path). It is what the rest of ROGER needs to know about a robot beyond its vector sizes:

* the **names** of the perception and action entries (dataset columns and LeRobot feature
  names, JSON log fields: :mod:`roger_daemon.datasets`, ``roger log export``);
* the **ranges** of the entries: each is mapped onto [-1, 1], the scaled units the learner's
  ``"default"`` preset is for (:func:`roger_daemon.learner.params.range_scaling`);
* the inputs the learner **ignores** (input weight 0: state-free inputs such as a clock);
* the robot's rate (a dataset's fps) and a one-line task (a LeRobot dataset's task).

The daemon selects one per robot (``[[robots]] profile = "aibo"`` or a path, see
``configs/roger.toml``); from Python, ``load_profile("aibo").params("default")`` gives the
learner parameters the daemon would use. ``configs/robots/aibo.toml`` holds the numbers of
``protocols/aibo.py`` (a test checks that they agree to the last bit).

File format::

    name = "my_arm"                  # optional: the file's stem
    description = "..."              # optional
    task = "pick up the cube"        # optional: a dataset's task text
    rate_hz = 30.0                   # optional: the robot's perception rate
    [perception]
    names = ["j0", "j1", ...]        # one per perception entry
    ranges = [[-3.14, 3.14], ...]    # optional: (low, high) per entry
    ignore = ["clock"]               # optional: names the learner drops
    [action]
    names = [...]
    ranges = [...]
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from protocols.messages import Dims

__all__ = [
    "ProfileError",
    "RobotProfile",
    "generic_profile",
    "load_profile",
    "profile_for_dims",
    "shipped_profiles",
]

Range = tuple[float, float]


class ProfileError(ValueError):
    """A robot profile that is missing, unreadable or malformed (the message says which)."""


def _names(value: Any, where: str) -> tuple[str, ...]:
    if (not isinstance(value, list) or not value
            or not all(isinstance(n, str) and n for n in value)):
        raise ProfileError(f"{where} must be a non-empty array of names, got {value!r}")
    if len(set(value)) != len(value):
        dup = sorted({n for n in value if value.count(n) > 1})
        raise ProfileError(f"{where} must be unique; repeated: {', '.join(dup)}")
    return tuple(value)


def _ranges(value: Any, n: int, where: str) -> tuple[Range, ...] | None:
    if value is None:
        return None
    ok = isinstance(value, list) and len(value) == n
    out: list[Range] = []
    for r in value if ok else ():
        if not (isinstance(r, list) and len(r) == 2
                and all(isinstance(v, int | float) and not isinstance(v, bool)
                        and math.isfinite(v) for v in r) and r[1] > r[0]):
            ok = False
            break
        out.append((float(r[0]), float(r[1])))
    if not ok:
        raise ProfileError(f"{where} must be an array of {n} [low, high] pairs with high > low, "
                           f"got {value!r}")
    return tuple(out)


@dataclass(frozen=True)
class RobotProfile:
    """What ROGER knows about one robot's vectors (module docstring)."""

    name: str
    x_names: tuple[str, ...]
    y_names: tuple[str, ...]
    x_ranges: tuple[Range, ...] | None = None
    y_ranges: tuple[Range, ...] | None = None
    ignore: tuple[str, ...] = ()
    rate_hz: float = 30.0
    description: str = ""
    task: str = ""

    @property
    def dims(self) -> Dims:
        """Perception and action sizes."""
        return Dims(len(self.x_names), len(self.y_names))

    def input_weights(self) -> tuple[float, ...] | None:
        """0 for every ignored input, 1 elsewhere (``None`` if nothing is ignored)."""
        if not self.ignore:
            return None
        return tuple(0.0 if n in self.ignore else 1.0 for n in self.x_names)

    def scaling(self) -> dict[str, list[float]]:
        """The learner parameters this profile sets: the ranges' scaling, the input weights."""
        from roger_daemon.learner.params import range_scaling

        out: dict[str, list[float]] = {}
        for axis, ranges in (("x", self.x_ranges), ("y", self.y_ranges)):
            if ranges is not None:
                offset, scale = range_scaling(ranges)
                out[f"{axis}_offset"], out[f"{axis}_scale"] = list(offset), list(scale)
        weights = self.input_weights()
        if weights is not None:
            out["input_weights"] = list(weights)
        return out

    def params(self, preset: str = "default", **changes: Any) -> Any:
        """``RogerParams`` of ``preset`` with this profile's scaling (``changes`` on top),
        ``nu0`` resolved for the robot's perception size."""
        from roger_daemon.learner.params import PRESETS, ParameterError, RogerParams

        if preset not in PRESETS:
            raise ParameterError(f"preset must be one of {', '.join(map(repr, PRESETS))}, "
                                 f"got {preset!r}")
        params = RogerParams.from_mapping({**PRESETS[preset], **self.scaling(), **changes})
        params.check_dims(self.dims.x, self.dims.y)
        return params.for_dims(self.dims.x)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready form (session metadata, dataset metadata); :meth:`from_mapping` reads it."""
        def table(names: tuple[str, ...], ranges: tuple[Range, ...] | None) -> dict[str, Any]:
            out: dict[str, Any] = {"names": list(names)}
            if ranges is not None:
                out["ranges"] = [list(r) for r in ranges]
            return out

        perception = table(self.x_names, self.x_ranges)
        if self.ignore:
            perception["ignore"] = list(self.ignore)
        return {"name": self.name, "description": self.description, "task": self.task,
                "rate_hz": self.rate_hz, "perception": perception,
                "action": table(self.y_names, self.y_ranges)}

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], name: str = "") -> RobotProfile:
        """Validate a parsed profile (a TOML document or :meth:`to_mapping`'s output)."""
        known = {"name", "description", "task", "rate_hz", "perception", "action"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ProfileError(f"unknown key(s) {', '.join(unknown)}; a profile has "
                               f"{', '.join(sorted(known))}")
        sections: list[dict[str, Any]] = []
        for sec, keys in (("perception", {"names", "ranges", "ignore"}),
                          ("action", {"names", "ranges"})):
            table = data.get(sec)
            if not isinstance(table, dict):
                raise ProfileError(f"[{sec}] must be a table with names = [...]")
            extra = sorted(set(table) - keys)
            if extra:
                raise ProfileError(f"unknown key(s) {sec}.{', '.join(extra)}")
            sections.append(table)
        xt, yt = sections
        x_names = _names(xt.get("names"), "perception.names")
        y_names = _names(yt.get("names"), "action.names")
        ignore = tuple(xt.get("ignore", ()))
        missing = [n for n in ignore if n not in x_names]
        if missing or len(ignore) >= len(x_names):
            raise ProfileError(f"perception.ignore must name some (not all) perception names, "
                               f"got {list(ignore)!r}")
        rate = data.get("rate_hz", 30.0)
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
            raise ProfileError(f"rate_hz must be a number > 0, got {rate!r}")
        text = {k: data.get(k, "") for k in ("name", "description", "task")}
        for k, v in text.items():
            if not isinstance(v, str):
                raise ProfileError(f"{k} must be a string, got {v!r}")
        return cls(name=text["name"] or name, x_names=x_names, y_names=y_names,
                   x_ranges=_ranges(xt.get("ranges"), len(x_names), "perception.ranges"),
                   y_ranges=_ranges(yt.get("ranges"), len(y_names), "action.ranges"),
                   ignore=ignore, rate_hz=float(rate), description=text["description"],
                   task=text["task"])


def _shipped_dir() -> Any:
    return resources.files("roger_daemon") / "configs" / "robots"


def shipped_profiles() -> tuple[str, ...]:
    """Names of the profiles shipped in ``configs/robots/``."""
    return tuple(sorted(p.name[:-5] for p in _shipped_dir().iterdir()
                        if p.name.endswith(".toml")))


def is_path(spec: str) -> bool:
    """Whether a profile reference is a file path (has a ``/`` or ends in ``.toml``)."""
    return "/" in spec or spec.endswith(".toml")


def load_profile(spec: str | Path) -> RobotProfile:
    """A shipped profile by name (``"aibo"``), or the profile file at a path."""
    if isinstance(spec, Path) or is_path(spec):
        path = Path(spec)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ProfileError(f"cannot read robot profile {path}: {exc.strerror or exc}"
                               ) from None
        where, name = str(path), path.stem
    else:
        names = shipped_profiles()
        if spec not in names:
            raise ProfileError(f"no shipped robot profile {spec!r}; shipped: "
                               f"{', '.join(names)} (or give a path to a .toml file)")
        text = (_shipped_dir() / f"{spec}.toml").read_text(encoding="utf-8")
        where, name = f"configs/robots/{spec}.toml", spec
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{where} is not valid TOML: {exc}") from None
    try:
        return RobotProfile.from_mapping(data, name)
    except ProfileError as exc:
        raise ProfileError(f"{where}: {exc}") from None


def generic_profile(dims: Dims, name: str = "") -> RobotProfile:
    """Names ``x0 .. x{n-1}`` and ``y0 ..``, no ranges: a robot without a profile."""
    return RobotProfile(name=name, x_names=tuple(f"x{i}" for i in range(dims.x)),
                        y_names=tuple(f"y{i}" for i in range(dims.y)))


def profile_for_dims(dims: Dims, names: Sequence[str] = ()) -> RobotProfile:
    """The first of the shipped profiles ``names`` (all by default) with these dimensions,
    else :func:`generic_profile`."""
    for n in names or shipped_profiles():
        p = load_profile(n)
        if p.dims == dims:
            return p
    return generic_profile(dims)

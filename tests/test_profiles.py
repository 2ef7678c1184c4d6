"""Robot profiles as data (configs/robots/*.toml, roger_daemon.profiles)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocols import aibo
from protocols.messages import Dims
from roger_daemon.config import ConfigError, parse_config
from roger_daemon.learner import Roger, RogerParams
from roger_daemon.profiles import (
    ProfileError,
    generic_profile,
    load_profile,
    profile_for_dims,
    shipped_profiles,
)


def test_the_aibo_profile_is_protocols_aibo_to_the_last_bit() -> None:
    p = load_profile("aibo")
    assert "aibo" in shipped_profiles()
    assert p.x_names == aibo.PERCEPTION_NAMES and p.y_names == aibo.ACTION_NAMES
    assert p.x_ranges == aibo.PERCEPTION_RANGES and p.y_ranges == aibo.ACTION_RANGES
    assert [p.x_names.index(n) for n in p.ignore] == list(aibo.STATE_FREE_DIMS)
    assert p.dims == aibo.DIMS and p.rate_hz == 30.0


def test_the_daemon_config_of_the_aibo_is_unchanged_by_the_profile_file() -> None:
    """The scaling the parser used to compute from protocols.aibo, bit for bit."""
    lo, hi = np.array(aibo.PERCEPTION_RANGES).T
    ylo, yhi = np.array(aibo.ACTION_RANGES).T
    params = parse_config({}).robots[0].params
    assert params.x_offset == tuple(0.5 * (lo + hi)) and params.x_scale == tuple(0.5 * (hi - lo))
    assert params.y_offset == tuple(0.5 * (ylo + yhi))
    assert params.y_scale == tuple(0.5 * (yhi - ylo))
    assert params.input_weights == tuple(0.0 if i in (21, 22) else 1.0 for i in range(23))
    assert params == load_profile("aibo").params("default")


def write_profile(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


ARM = """
name = "arm6"
task = "reach"
rate_hz = 20
[perception]
names = ["j0", "j1", "j2", "j3", "j4", "clock"]
ranges = [[-3, 3], [-3, 3], [-3, 3], [-3, 3], [0, 1], [0, 100]]
ignore = ["clock"]
[action]
names = ["vx", "vy"]
ranges = [[-0.5, 0.5], [-1, 1]]
"""


def test_a_profile_file_selected_by_path_in_robots(tmp_path: Path) -> None:
    path = write_profile(tmp_path / "arm6.toml", ARM)
    robot = parse_config({"robots": [{"id": "arm", "profile": str(path)}]}).robots[0]
    assert (robot.x_dim, robot.y_dim) == (6, 2)  # from the profile
    assert robot.robot_profile.y_names == ("vx", "vy")
    p = robot.params
    assert p.x_offset == (0.0, 0.0, 0.0, 0.0, 0.5, 50.0) and p.y_scale == (0.5, 1.0)
    assert p.input_weights == (1.0,) * 5 + (0.0,) and p.nu0 == 7.0
    assert p.theta_w == RogerParams.preset("default").theta_w
    Roger(6, 2, p)  # a valid model


def test_declared_ranges_in_robots_scale_without_a_profile() -> None:
    robot = parse_config({"robots": [{"id": "cart", "x_dim": 2, "y_dim": 1,
                                      "x_ranges": [[0, 4], [-1, 1]],
                                      "y_ranges": [[-10, 10]]}]}).robots[0]
    assert robot.profile == "none" and robot.params.x_offset == (2.0, 0.0)
    assert robot.params.x_scale == (2.0, 1.0) and robot.params.y_scale == (10.0,)
    assert robot.params.nu0 == 3.0


@pytest.mark.parametrize(("text", "message"), [
    ("[perception]\nnames = []\n[action]\nnames = ['a']\n", "perception.names must be"),
    ("[perception]\nnames = ['a', 'a']\n[action]\nnames = ['b']\n", "repeated: a"),
    ("[perception]\nnames = ['a']\nranges = [[1, 0]]\n[action]\nnames = ['b']\n",
     "perception.ranges must be an array of 1 [low, high] pairs"),
    ("[perception]\nnames = ['a', 'b']\nignore = ['c']\n[action]\nnames = ['b']\n",
     "perception.ignore must name some"),
    ("colour = 1\n[perception]\nnames = ['a']\n[action]\nnames = ['b']\n", "unknown key(s) colour"),
    ("[perception\n", "is not valid TOML"),
])
def test_bad_profiles_are_refused_naming_the_problem(tmp_path: Path, text: str,
                                                     message: str) -> None:
    path = write_profile(tmp_path / "bad.toml", text)
    with pytest.raises(ProfileError, match="bad.toml") as exc:
        load_profile(path)
    assert message in str(exc.value)
    with pytest.raises(ConfigError, match=r"robots\[0\]\.profile"):
        parse_config({"robots": [{"id": "x", "profile": str(path)}]})


def test_profile_for_dims_and_the_generic_names() -> None:
    assert profile_for_dims(Dims(23, 9)).name == "aibo"
    generic = profile_for_dims(Dims(3, 2))
    assert generic == generic_profile(Dims(3, 2)) and generic.x_names == ("x0", "x1", "x2")
    p = load_profile("aibo")
    assert type(p).from_mapping(p.to_mapping()) == p

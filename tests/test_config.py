"""The daemon config validator: defaults, the shipped file, and every promised message."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roger_daemon.config import ConfigError, apply_overrides, load_config, parse_config

ROOT = Path(__file__).resolve().parents[1]


def test_defaults_are_the_documented_ones() -> None:
    cfg = parse_config({})
    assert cfg.clock == "realtime" and cfg.rate_hz == 30.0 and cfg.status_hz == 1.0
    assert [r.id for r in cfg.robots] == ["aibo"]
    assert (cfg.robots[0].x_dim, cfg.robots[0].y_dim) == (23, 9)
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:7447",) and cfg.zenoh.mode == "peer"
    assert cfg.zenoh.multicast_scouting is False
    assert cfg.robots[0].params.alpha == 0.5 and cfg.robots[0].params.beta == 300


def test_shipped_config_is_valid_and_equals_the_defaults() -> None:
    cfg = load_config(ROOT / "configs/roger.toml")
    default = parse_config({})
    assert cfg.robots[0].params == default.robots[0].params
    assert (cfg.clock, cfg.rate_hz, cfg.queue_size, cfg.mode) == (
        default.clock, default.rate_hz, default.queue_size, default.mode)
    assert cfg.zenoh == default.zenoh and cfg.checkpoint == default.checkpoint


def test_config_is_immutable() -> None:
    cfg = parse_config({})
    with pytest.raises(AttributeError):
        cfg.rate_hz = 10.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        cfg.learner["alpha"] = 1.0  # type: ignore[index]


def test_several_robots_with_scaling() -> None:
    cfg = parse_config({
        "robots": [
            {"id": "aibo"},
            {"id": "arm_1", "x_dim": 2, "y_dim": 1, "model": "unimap", "seed": 7,
             "x_scale": [2.0, 4.0], "y_offset": [0.5]},
        ],
        "learner": {"alpha": 1.5, "nu0": 24},
    })
    arm = cfg.robot("arm_1")
    assert arm.model == "unimap" and arm.seed == 7
    assert arm.params.x_scale == (2.0, 4.0) and arm.params.y_offset == (0.5,)
    assert arm.params.alpha == 1.5 and arm.profile == "none"
    assert cfg.robot("aibo").profile == "aibo" and cfg.robot("aibo").params.x_scale is not None


def test_presets_and_the_aibo_profile() -> None:
    from protocols.aibo import ACTION_RANGES, PERCEPTION_RANGES
    from roger_daemon.learner import RogerParams
    from roger_daemon.learner.scaling import AffineScaling

    default = parse_config({}).robots[0]
    assert default.profile == "aibo"
    p = default.params
    assert p.replace(x_offset=None, x_scale=None, y_offset=None, y_scale=None,
                     input_weights=None) == RogerParams.preset("default").for_dims(23)
    assert p.nu0 == 24.0  # derived from x_dim (23 + 1): the value it always had
    sc = AffineScaling(p, 23, 9)
    lo, hi = (np.array(r) for r in zip(*PERCEPTION_RANGES, strict=True))
    kept = [i for i in range(23) if i not in (21, 22)]  # the tail inputs are dropped
    np.testing.assert_allclose(sc.x_in(lo), -np.ones(21), atol=1e-12)
    np.testing.assert_allclose(sc.x_in(hi), np.ones(21), atol=1e-12)
    np.testing.assert_allclose(sc.x_in(0.5 * (lo + hi)), 0.0, atol=1e-12)
    assert sc.d_model == 21 and len(kept) == 21
    ylo, yhi = (np.array(r) for r in zip(*ACTION_RANGES, strict=True))
    np.testing.assert_allclose(sc.y_in(ylo), -1.0, atol=1e-12)
    np.testing.assert_allclose(sc.mean_out(np.ones(9)), yhi, atol=1e-12)
    np.testing.assert_allclose(sc.var_out(1.0), ((yhi - ylo) / 2) ** 2, rtol=1e-12)
    # the paper preset: the paper's numbers on raw data (no profile), unless asked for
    paper = parse_config({"learner": {"preset": "paper"}}).robots[0]
    assert paper.profile == "none" and paper.params == RogerParams().for_dims(23)
    both = parse_config({"learner": {"preset": "paper"},
                         "robots": [{"id": "aibo", "profile": "aibo"}]}).robots[0]
    assert both.params.theta_w == 0.1 and both.params.x_scale == p.x_scale
    # a robot's own keys override its profile's; learner keys override the preset
    own = parse_config({"learner": {"theta_w": 3.0},
                        "robots": [{"id": "aibo", "input_weights": [1.0] * 23,
                                    "y_scale": [2.0] * 9}]}).robots[0]
    assert own.params.input_weights == (1.0,) * 23 and own.params.y_scale == (2.0,) * 9
    assert own.params.x_scale == p.x_scale and own.params.theta_w == 3.0


BAD: list[tuple[dict[str, Any], str]] = [
    ({"daemon": {"rate_hz": "fast"}}, 'daemon.rate_hz must be a number > 0, got "fast"'),
    ({"daemon": {"rate_hz": 0}}, "daemon.rate_hz must be a number > 0, got 0"),
    ({"daemon": {"rate_hz": 5000.0}},
     "daemon.rate_hz must be a number > 0 and <= 1000, got 5000.0"),
    ({"daemon": {"clock": "wall"}},
     'daemon.clock must be one of "realtime", "lockstep", got "wall"'),
    ({"daemon": {"mode": "train"}}, 'daemon.mode must be one of "learn", "predict", '
                                    '"learn+predict", "pause", got "train"'),
    ({"daemon": {"queue_size": 0}}, "daemon.queue_size must be an integer >= 1, got 0"),
    ({"daemon": {"queue_size": 1.5}}, "daemon.queue_size must be an integer >= 1, got 1.5"),
    ({"daemon": {"seed": -1}}, "daemon.seed must be an integer >= 0, got -1"),
    ({"daemon": {"id": "my daemon"}},
     'daemon.id must be a string of 1-64 characters [A-Za-z0-9_-], got "my daemon"'),
    ({"daemon": {"count_unserved": "yes"}},
     'daemon.count_unserved must be true or false, got "yes"'),
    ({"daemon": {"rat_hz": 30}}, "unknown key daemon.rat_hz"),
    ({"bogus": {}}, "unknown key bogus"),
    ({"daemon": 3}, "daemon must be a table, got 3"),
    ({"learner": {"alpha": -1.0}}, "learner.alpha must be a float > 0, got -1.0"),
    ({"learner": {"beta": 0}}, "learner.beta must be an integer >= 1, got 0"),
    ({"learner": {"alhpa": 1.0}}, "learner: unknown parameter(s) 'alhpa'"),
    ({"learner": {"preset": "paper", "nu0": 5.0}}, "learner.nu0 must be a float > d_x - 1 = 22"),
    ({"learner": {"nu0": 5.0}}, "learner.nu0 must be a float > d_x - 1 = 20 for d_x = 21 "
                                "(input dimensions kept by input_weights: 21), got 5.0"),
    ({"learner": {"preset": "fast"}},
     'learner.preset must be one of "paper", "default", got "fast"'),
    ({"learner": {"sticky_kappa": -1}}, "learner.sticky_kappa must be a float >= 0, got -1"),
    ({"learner": {"min_support": 2.5}}, "learner.min_support must be an integer >= 0, got 2.5"),
    ({"learner": {"gp_prior_mean": "data"}},
     "learner.gp_prior_mean must be one of 'zero', 'expert', got 'data'"),
    ({"robots": [{"id": "a", "profile": "arm"}]},
     "robots[0].profile: no shipped robot profile 'arm'; shipped: aibo"),
    ({"robots": [{"id": "a", "profile": "missing/arm.toml"}]},
     "robots[0].profile: cannot read robot profile missing/arm.toml"),
    ({"robots": [{"id": "a", "x_dim": 2, "profile": "aibo"}]},
     'robots[0].profile must be "none" or a profile of 2 perception and 9 action names for a '
     "robot with x_dim, y_dim = 2, 9 (profile 'aibo' has 23, 9)"),
    ({"robots": [{"id": "a", "x_dim": 2, "x_ranges": [[0, 1], [1, 1]]}]},
     "robots[0].x_ranges must be an array of 2 [low, high] pairs of numbers with high > low"),
    ({"robots": [{"id": "a", "x_dim": 2, "input_weights": [0.0, 0.0]}]},
     "robots[0].input_weights must be an array of 2 numbers >= 0, not all 0, got [0.0, 0.0]"),
    ({"robots": []}, "robots must be a non-empty array of tables ([[robots]]), got []"),
    ({"robots": [{"x_dim": 3}]}, "robots[0].id is required"),
    ({"robots": [{"id": "a"}, {"id": "a"}]}, 'robots[1].id must be unique among robots, got "a"'),
    ({"robots": [{"id": "a", "x_dim": 0}]}, "robots[0].x_dim must be an integer >= 1, got 0"),
    ({"robots": [{"id": "a", "model": "gp"}]},
     'robots[0].model must be one of "roger", "unimap", "roger+fsm", got "gp"'),
    ({"robots": [{"id": "a", "x_dim": 2, "x_scale": [1.0]}]},
     "robots[0].x_scale must be an array of 2 finite numbers, got [1.0]"),
    ({"robots": [{"id": "a", "x_dim": 2, "x_scale": [1.0, 0.0]}]},
     "robots[0].x_scale must be an array of 2 numbers > 0, got [1.0, 0.0]"),
    ({"robots": [{"id": "a", "colour": "red"}]}, "unknown key robots[0].colour"),
    ({"zenoh": {"mode": "router"}}, 'zenoh.mode must be one of "peer", "client", got "router"'),
    ({"zenoh": {"listen": "tcp/127.0.0.1:7447"}},
     'zenoh.listen must be an array of strings, got "tcp/127.0.0.1:7447"'),
    ({"zenoh": {"connect": ["localhost"]}},
     'zenoh.connect must be an array of endpoints like "tcp/127.0.0.1:7447", got ["localhost"]'),
    ({"zenoh": {"mode": "client"}},
     'zenoh.connect must be at least one endpoint when zenoh.mode is "client", got []'),
    ({"zenoh": {"lease_ms": 5}}, "zenoh.lease_ms must be an integer >= 100 (milliseconds), got 5"),
    ({"zenoh": {"config_file": "/nonexistent/z.json5"}},
     'zenoh.config_file must be a readable Zenoh JSON5 config, got "/nonexistent/z.json5"'),
    ({"checkpoint": {"every_s": -1}}, "checkpoint.every_s must be a number >= 0, got -1"),
    ({"checkpoint": {"keep": 0}}, "checkpoint.keep must be an integer >= 1, got 0"),
    ({"checkpoint": {"shutdown_learn_s": 10}},
     "checkpoint.shutdown_learn_s must be a number in [0, 3] (seconds), got 10.0"),
    ({"checkpoint": {"dir": 5}}, "checkpoint.dir must be a directory (a non-empty path), got 5"),
    ({"recording": {"enabled": 1}}, "recording.enabled must be true or false, got 1"),
]


@pytest.mark.parametrize(("raw", "message"), BAD, ids=[m.split(" ")[0] for _, m in BAD])
def test_bad_values_are_rejected_naming_key_form_and_value(raw: dict[str, Any],
                                                           message: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_config(raw)
    assert str(err.value).startswith("config error: ")
    assert message in str(err.value)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[daemon\nrate_hz = 3\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="is not valid TOML"):
        load_config(bad)


def test_overrides_are_toml_values_and_validated(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text('[daemon]\nclock = "realtime"\n', encoding="utf-8")
    cfg = load_config(f, ["daemon.clock=lockstep", "daemon.rate_hz=60", "learner.alpha=2.5",
                          'zenoh.listen=["tcp/127.0.0.1:9000"]'])
    assert cfg.clock == "lockstep" and cfg.rate_hz == 60.0
    assert cfg.robots[0].params.alpha == 2.5 and cfg.zenoh.listen == ("tcp/127.0.0.1:9000",)
    with pytest.raises(ConfigError, match='daemon.rate_hz must be a number > 0, got "fast"'):
        load_config(f, ["daemon.rate_hz=fast"])
    with pytest.raises(ConfigError, match="must look like SECTION.KEY=VALUE"):
        apply_overrides({}, ["daemon.rate_hz"])
    with pytest.raises(ConfigError, match="must be SECTION.KEY"):
        apply_overrides({}, ["rate_hz=3"])


def test_zenoh_file_leaves_unset_keys_to_the_file() -> None:
    cfg = parse_config({"zenoh": {"config_file": str(ROOT / "configs/zenoh/client.json5")}})
    assert cfg.zenoh.mode is None and cfg.zenoh.listen is None and cfg.zenoh.connect is None
    cfg = parse_config({"zenoh": {"config_file": str(ROOT / "configs/zenoh/client.json5"),
                                  "connect": ["tcp/10.0.0.2:7447"]}})
    assert cfg.zenoh.connect == ("tcp/10.0.0.2:7447",)


def test_every_default_the_parser_gives_is_the_dataclasses_own() -> None:
    from dataclasses import fields

    from roger_daemon.config import CheckpointConfig, DaemonConfig, RecordingConfig

    cfg = parse_config({})
    for section, cls in ((cfg, DaemonConfig), (cfg.checkpoint, CheckpointConfig),
                         (cfg.recording, RecordingConfig)):
        for f in fields(cls):
            if f.name in ("robots", "learner", "zenoh", "checkpoint", "recording", "dir"):
                continue
            assert getattr(section, f.name) == getattr(cls(), f.name), f.name
    assert cfg.checkpoint.dir == CheckpointConfig.dir.absolute()


def test_a_recorded_configs_daemon_table_is_read_by_the_parser_alone() -> None:
    from roger_daemon.config import daemon_settings

    # the other sections are not read: a recorded config may name files this machine lacks
    text = ('[daemon]\npair_window = 100\n[zenoh]\nconfig_file = "/nowhere.json5"\n'
            '[[robots]]\nid = "arm"\nprofile = "/nowhere.toml"\n')
    assert daemon_settings(text)["pair_window"] == 100
    assert daemon_settings("")["pair_window"] == parse_config({}).pair_window
    with pytest.raises(ConfigError, match="daemon.pair_window must be an integer >= 1"):
        daemon_settings("[daemon]\npair_window = 0\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        daemon_settings("[daemon\n")


def test_a_robot_the_config_does_not_list_is_resolved_as_if_listed() -> None:
    from protocols.messages import Dims
    from roger_daemon.config import robot_config

    cfg = parse_config({"daemon": {"seed": 4}, "learner": {"theta_n": 0.3},
                        "robots": [{"id": "arm", "x_dim": 2, "y_dim": 1, "model": "unimap"}]})
    assert robot_config(cfg, "arm", Dims(5, 5)) is cfg.robots[0]
    other = robot_config(cfg, "aibo", Dims(23, 9))
    listed = parse_config({"daemon": {"seed": 4}, "learner": {"theta_n": 0.3},
                           "robots": [{"id": "aibo", "x_dim": 23, "y_dim": 9}]}).robots[0]
    assert other == listed and other.params.theta_n == 0.3 and other.seed == 4

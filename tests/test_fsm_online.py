"""The daemon's model kind ``roger+fsm`` (roger_daemon/fsm/online.py): ROGER's experts bit for
bit, the transitions learned pair by pair, in the state dict, checkpointed and replayed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from daemon_sessions import record_session

from roger_daemon.config import ConfigError, parse_config
from roger_daemon.config.models import build_model as make_daemon_model
from roger_daemon.config.models import load_model as load_daemon_model
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.fsm.online import RogerFSM, has_fsm
from roger_daemon.learner import Roger, RogerParams
from roger_daemon.learner.synthetic import subtask_stream
from roger_daemon.replay import replay_session
from roger_daemon.replay.compare import REL_TOL

PARAMS = RogerParams(nu0=24.0)


@pytest.fixture(scope="module")
def stream() -> tuple[np.ndarray, np.ndarray]:
    s = subtask_stream(160)
    return s.x, s.y


def test_experts_are_roger_s_bit_for_bit(stream: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream
    plain, fsm = Roger(23, 9, PARAMS, seed=3), RogerFSM(23, 9, PARAMS, seed=3)
    for i in range(len(x)):
        plain.learn_one(x[i], y[i])
        fsm.learn_one(x[i], y[i])
    assert array_digest(plain.state_dict()) == array_digest(fsm.experts_state())
    assert has_fsm(fsm.state_dict()) and not has_fsm(plain.state_dict())
    # every pair after the first taught one transition, each from the MAP assignment
    t = fsm.fsm.transitions
    assert int(t.count.sum()) == len(x) - 1 and -1 not in t.sources()
    # the state is the MAP particle's expert of the pair as it was learned (the newest one's
    # is still the model's; earlier ones may have been revised since: not taught again)
    assert fsm.fsm.state_dict()["meta"] and int(fsm.assignments()[-1]) == _learn_state(fsm)
    assert fsm.fsm.n_observed == len(x)


def _learn_state(model: RogerFSM) -> int:
    import json

    return int(json.loads(str(model.fsm.state_dict()["meta"]))["state"])


def test_state_dict_round_trips_and_continues_exactly(
        tmp_path: Path, stream: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream
    a = RogerFSM(23, 9, PARAMS, seed=1)
    for i in range(100):
        a.learn_one(x[i], y[i])
    np.savez(tmp_path / "s.npz", **a.state_dict())
    with np.load(tmp_path / "s.npz", allow_pickle=False) as z:
        b = load_daemon_model({k: z[k] for k in z.files})
    assert isinstance(b, RogerFSM)
    for i in range(100, len(x)):
        a.learn_one(x[i], y[i])
        b.learn_one(x[i], y[i])
    assert array_digest(a.state_dict()) == array_digest(b.state_dict())


def test_an_old_plain_state_still_loads(stream: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream
    plain = Roger(23, 9, PARAMS, seed=0)
    for i in range(40):
        plain.learn_one(x[i], y[i])
    state = plain.state_dict()
    assert type(load_daemon_model(state)) is Roger  # a plain checkpoint stays plain
    upgraded = RogerFSM.from_state_dict(state)  # the transitions start empty
    assert upgraded.n_learned == 40 and upgraded.fsm.n_observed == 0
    assert array_digest(upgraded.experts_state()) == array_digest(state)


def test_config_names_the_kind_and_rejects_other_robots() -> None:
    cfg = parse_config({"robots": [{"id": "aibo", "model": "roger+fsm"}]})
    assert cfg.robots[0].model == "roger+fsm"
    with pytest.raises(ConfigError, match="roger\\+fsm"):
        parse_config({"robots": [{"id": "r", "x_dim": 2, "y_dim": 1, "model": "roger+fsm"}]})
    with pytest.raises(ValueError, match="unknown model kind 'fsm'"):
        make_daemon_model("fsm", 23, 9, PARAMS, 0)


@pytest.mark.parametrize("workers", [False, True])
def test_a_daemon_session_replays_bit_identically(tmp_path: Path, workers: bool) -> None:
    s = record_session(tmp_path, n_ticks=70, stream="subtask", checkpoint_at=(40,),
                       robot_options={"model": "roger+fsm"}, workers=workers)
    assert has_fsm(s.checkpoints[40])
    model = load_daemon_model(s.checkpoints[40])
    assert isinstance(model, RogerFSM) and model.fsm.n_observed == 40
    res = replay_session(s.paths[0])
    assert res.ok(REL_TOL), res.summary(REL_TOL)
    assert res.model_kind == "roger+fsm" and res.digests and all(d.match for d in res.digests)
    assert res.bit_identical()
    assert isinstance(res.model, RogerFSM) and res.model.fsm.n_observed == 70


def test_a_plain_session_replayed_with_transitions_keeps_its_digests(tmp_path: Path) -> None:
    s = record_session(tmp_path, n_ticks=50, stream="subtask", checkpoint_at=(30,))
    res = replay_session(s.paths[0], model_kind="roger+fsm")
    assert res.digests and all(d.match for d in res.digests)  # the experts' part
    assert isinstance(res.model, RogerFSM) and res.model.fsm.n_observed == 50


def test_an_override_sets_the_model_of_every_robot() -> None:
    from roger_daemon.config import load_config

    cfg = load_config(None, ['robots.model="roger+fsm"'])
    assert [r.model for r in cfg.robots] == ["roger+fsm"] and cfg.robots[0].id == "aibo"
    with pytest.raises(ConfigError, match=r"robots\[0\].model must be one of"):
        load_config(None, ["robots.model=fsm"])


def test_up_plays_with_roger_play_and_no_hcc(tmp_path: Path) -> None:
    from simulator.launch import plan

    p = plan({"controller": {"role": "play"}, "ports": {"daemon": 17447, "sim": 17450}},
             tmp_path)
    ctl = p.argv["controller"]
    assert ctl[ctl.index("-m") + 2: ctl.index("-m") + 5] == ["play", "--checkpoint",
                                                            "checkpoints"]
    assert "hcc" not in ctl and 'daemon.mode="predict"' in p.argv["daemon"]

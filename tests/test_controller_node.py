"""The controller nodes' one loop (simulator/controllers/node.py): shared arguments and the
perception rules (repeated tick resent, older tick stale, ``t == 0`` a new episode)."""

from __future__ import annotations

import argparse
import logging
from typing import Any

import numpy as np
import pytest

from protocols import Command, Perception, Prediction
from protocols.aibo import DIMS
from simulator.controllers import hcc_node, node, play_node
from simulator.experiment import dpa_node
from simulator.transport import StopFlag

SHARED = ("robot", "exit_when_done", "idle_exit", "stats")
PREDICTION = ("clock", "prediction_timeout", "max_prediction_age")


def _parse(configure: Any, argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure(p)
    return p.parse_args(argv)


def test_the_three_nodes_share_one_set_of_arguments() -> None:
    argv = ["--robot", "r2", "--exit-when-done", "--idle-exit", "1.5", "--stats", "s.json"]
    pred = ["--clock", "realtime", "--prediction-timeout", "0.5", "--max-prediction-age", "7"]
    got = [_parse(play_node.configure, ["--checkpoint", "c", *argv, *pred]),
           _parse(hcc_node.configure, [*argv, *pred]),
           _parse(dpa_node.configure, argv)]
    for ns in got:
        assert [getattr(ns, k) for k in SHARED] == ["r2", True, 1.5, "s.json"]
    for ns in got[:2]:
        assert [getattr(ns, k) for k in PREDICTION] == ["realtime", 0.5, 7]
    assert not hasattr(got[2], "clock")  # the DPA is driven by predictions


class _Echo(node.PerceptionNode):
    """Commands its perception's tick; counts its episodes."""

    def __init__(self) -> None:
        args = argparse.Namespace(robot="aibo", clock="lockstep")
        super().__init__(args, StopFlag(install=False), "echo", logging.getLogger("t"))
        self.resets = 0

    def new_episode(self) -> None:
        self.resets += 1

    def command_for(self, msg: Perception) -> Command:
        return Command(self.robot, msg.tick, msg.t, y=np.full(DIMS.y, float(msg.tick)),
                       source="echo")


def test_a_repeated_tick_is_resent_an_older_one_stale_and_t0_a_new_episode(
        monkeypatch: pytest.MonkeyPatch) -> None:
    sent: list[Command] = []
    monkeypatch.setattr(node.transport, "put", lambda _pub, msg: sent.append(msg))
    n = _Echo()
    n.pub_cmd = None
    x = np.zeros(DIMS.x)
    for tick, t in ((0, 0.0), (1, 1 / 30), (1, 1 / 30), (0, 0.5), (2, 2 / 30), (0, 0.0)):
        n._on_message(Perception("aibo", tick, t, x=x))
    assert [c.tick for c in sent] == [0, 1, 1, 2, 0]
    assert n.counts == {"perceptions": 6, "commands": 4, "resent": 1, "stale_perceptions": 1,
                        "episodes": 2}
    assert n.resets == 2
    assert n.summary(extra=1)["extra"] == 1 and n.summary()["role"] == "echo"


class _Inbox:
    """A prediction inbox that hands out the given messages once."""

    def __init__(self, msgs: list[Prediction]) -> None:
        self.msgs = msgs

    def drain(self) -> list[Prediction]:
        out, self.msgs = self.msgs, []
        return out


def test_lockstep_takes_prediction_t_past_one_of_a_higher_tick() -> None:
    """A prediction of a higher tick (a stray daemon's on a reused port; the short demo's play
    stage once held none but its first this way) hides neither prediction(t) nor later ones."""
    n = _Echo()
    n.args.prediction_timeout = 0.05
    x, mean, var = np.zeros(DIMS.x), np.zeros(DIMS.y), np.ones(DIMS.y)

    def pred(tick: int) -> Prediction:
        return Prediction("aibo", tick, tick / 30, mean=mean, var=var, expert=-1)

    n.preds = _Inbox([pred(0), pred(500)])  # type: ignore[assignment]
    got = n.prediction_for(Perception("aibo", 0, 0.0, x=x))
    assert got is not None and got.tick == 0
    n.preds = _Inbox([pred(501), pred(1)])  # type: ignore[assignment]
    got = n.prediction_for(Perception("aibo", 1, 1 / 30, x=x))
    assert got is not None and got.tick == 1
    n.preds = _Inbox([pred(502)])  # type: ignore[assignment]
    assert n.prediction_for(Perception("aibo", 2, 2 / 30, x=x)) is None  # timed out

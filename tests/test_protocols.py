"""The wire: round trips and every rejection reason."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocols import (
    Action,
    Command,
    Control,
    Dims,
    EpisodeEvent,
    ExpertOutput,
    Perception,
    Prediction,
    ProtocolError,
    Status,
    decode,
    encode,
    keys,
)
from protocols.aibo import DIMS

D = Dims(23, 9)


def _perception_map(**over: object) -> dict[str, object]:
    m: dict[str, object] = {
        "v": 1, "robot": "aibo", "tick": 5, "t": 0.1, "stamp_ns": 7, "x": [0.0] * 23,
    }
    m.update(over)
    return m


def test_aibo_dims() -> None:
    assert DIMS == D


@pytest.mark.parametrize(
    "msg",
    [
        Perception("aibo", 1, 0.5, x=np.linspace(-1, 1, 23)),
        Action("aibo", 1, 0.5, y=np.arange(9.0), label="seek"),
        Command("aibo", 1, 0.5, y=np.arange(9.0), source="hcc"),
        Prediction(
            "aibo", 1, 0.5, mean=np.arange(9.0), var=np.ones(9), expert=3, latency_ms=1.5,
            multimap=(ExpertOutput(3, 0.7, np.zeros(9), np.ones(9), 12, "aim"),),
        ),
        EpisodeEvent("aibo", 1, 0.5, event="goal", episode=2, data={"location": 4}),
        Status(
            "aibo", 1, 0.5, daemon="d1", mode="learn", ticks=10, updates=9, updates_per_s=30.0,
            experts=2, queue_depth=0, dropped=0, invalid={"not_msgpack": 1},
        ),
        Control("aibo", 1, 0.5, op="mode", mode="predict"),
    ],
)
def test_round_trip(msg: object) -> None:
    assert hasattr(msg, "KIND")
    back = decode(msg.KIND, encode(msg), dims=D, robot="aibo")  # type: ignore[attr-defined]
    assert back.to_map() == msg.to_map()  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\xc1\xc1garbage", "not_msgpack"),
        (msgpack.packb([1, 2, 3]), "not_a_map"),
        (msgpack.packb(_perception_map(v=99)), "bad_version"),
        (msgpack.packb({k: v for k, v in _perception_map().items() if k != "x"}), "missing_field"),
        (msgpack.packb(_perception_map(x="hello")), "wrong_type"),
        (msgpack.packb(_perception_map(x=[0.0] * 22)), "wrong_dimension"),
        (msgpack.packb(_perception_map(x=[0.0] * 22 + [math.nan])), "not_finite"),
        (msgpack.packb(_perception_map(x=[0.0] * 22 + [math.inf])), "not_finite"),
        (msgpack.packb(_perception_map(tick=-1)), "bad_value"),
        (msgpack.packb(_perception_map(tick=1.5)), "wrong_type"),
        (msgpack.packb(_perception_map(robot="other")), "unknown_robot"),
        (b"\x00" * 70_000, "oversized"),
    ],
)
def test_rejections(payload: bytes, reason: str) -> None:
    with pytest.raises(ProtocolError) as info:
        decode("perception", payload, dims=D, robot="aibo")
    assert info.value.reason == reason
    assert str(info.value)  # a message a person can read


def test_keys_build_and_parse() -> None:
    assert keys.perception("aibo") == "roger/aibo/perception"
    assert keys.parse("roger/aibo/action") == ("aibo", "action")
    with pytest.raises(ProtocolError):
        keys.parse("roger/aibo/nonsense")
    with pytest.raises(ProtocolError):
        keys.perception("bad robot")


@given(st.binary(max_size=512))
def test_random_bytes_never_crash(payload: bytes) -> None:
    for kind in keys.KINDS:
        try:
            decode(kind, payload, dims=D)
        except ProtocolError:
            pass

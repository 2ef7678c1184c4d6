"""The wire: round trips and every rejection reason."""

from __future__ import annotations

import dataclasses
import math

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_recording import _samples

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
from protocols.field_specs import FieldSpec, field_spec
from protocols.keys import KINDS
from protocols.message_types import MODES

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


def _multimap_payload(entries: list[dict[str, object]]) -> bytes:
    pred = Prediction("aibo", 1, 0.5, mean=np.zeros(9), var=np.ones(9), expert=0, latency_ms=1.0,
                      multimap=())
    m = pred.to_map()
    m["multimap"] = entries
    out: bytes = msgpack.packb(m)
    return out


def _entry(i: int, **over: object) -> dict[str, object]:
    e: dict[str, object] = {"expert": i, "p": 0.5, "mean": [float(i)] * 8 + [1],
                            "var": [0.5] * 9, "n": 3, "label": "aim"}
    e.update(over)
    return e


def test_a_multimap_decodes_in_one_pass_to_what_each_entry_decodes_to() -> None:
    """The batch path of the prediction decoder against the entry-by-entry oracle."""
    from protocols.decoding import _expert

    entries = [_entry(i) for i in range(24)]
    got = decode("prediction", _multimap_payload(entries), dims=D, robot="aibo").multimap
    want = tuple(_expert(e, 9) for e in entries)
    assert [g.to_map() for g in got] == [w.to_map() for w in want]
    assert all(not g.mean.flags.writeable and g.mean.shape == (9,) for g in got)


@pytest.mark.parametrize(
    ("bad", "reason", "needle"),
    [
        ({"mean": [0.0] * 8}, "wrong_dimension", "'mean' must have 9 entries"),
        ({"var": [0.5] * 8 + [0.0]}, "bad_value", "'var' must be > 0"),
        ({"mean": [math.nan] + [0.0] * 8}, "not_finite", "'mean' contains NaN"),
        ({"mean": [True] + [0.0] * 8}, "wrong_type", "'mean' must contain only numbers"),
        ({"mean": [0.0] * 8 + ["1.5"]}, "wrong_type", "'mean' must contain only numbers"),
        ({"expert": "x"}, "wrong_type", "expert"),
        ({"mean": None}, "wrong_type", "'mean' must be an array"),
    ],
)
def test_a_bad_multimap_entry_among_good_ones_is_named(bad: dict[str, object], reason: str,
                                                       needle: str) -> None:
    entries = [_entry(i) for i in range(5)]
    entries[3] = _entry(3, **bad)
    with pytest.raises(ProtocolError) as err:
        decode("prediction", _multimap_payload(entries), dims=D, robot="aibo")
    assert err.value.reason == reason and needle in str(err.value)


# -- the field specs (the schemas' source) are the decoder's rules -------------------------

def _violation(sp: FieldSpec, value: object) -> object | None:
    """A value that breaks the field's spec, or None if the spec constrains nothing."""
    if sp.choices:
        return "zzz"
    if sp.pattern:
        return "not a robot id!"
    if sp.positive:
        return [0.0] * len(value)  # type: ignore[arg-type]
    if isinstance(value, int) and sp.minimum is not None:
        return sp.minimum - 1
    return None


@pytest.mark.parametrize("kind", KINDS)
def test_decoder_enforces_every_field_spec(kind: str) -> None:
    """The constraints the schemas are generated from are the decoder's: breaking any one of
    them (an enum, the robot pattern, a minimum, positivity; also inside a multimap entry) is a
    ``bad_value``."""
    msg = _samples()[kind]
    m = msgpack.unpackb(encode(msg), raw=False)  # type: ignore[arg-type]
    cases: list[dict[str, object]] = []
    for f in dataclasses.fields(type(msg)):
        bad = _violation(field_spec(f), m[f.name])
        if bad is not None:
            cases.append(dict(m, **{f.name: bad}))
    if kind == "prediction":
        for f in dataclasses.fields(ExpertOutput):
            entry = m["multimap"][0]
            bad = _violation(field_spec(f), entry[f.name])
            if bad is not None:
                cases.append(dict(m, multimap=[dict(entry, **{f.name: bad})]))
    assert cases  # every kind has the header's robot pattern and minimums
    for case in cases:
        with pytest.raises(ProtocolError) as err:
            decode(kind, msgpack.packb(case))
        assert err.value.reason == "bad_value", case



def test_action_source_and_correction_round_trip_and_older_actions_still_decode() -> None:
    """An action's source and correction (issue 54) survive the wire; an action of a log
    written before them (neither key) reads as source '' and correction false; a bad source
    is a bad_value, a correction that is not a bool a wrong_type."""
    act = Action("aibo", 3, 0.1, y=np.arange(9.0), label="", source="teacher", correction=True)
    back = decode("action", encode(act), dims=D)
    assert isinstance(back, Action) and (back.source, back.correction) == ("teacher", True)
    old = msgpack.unpackb(encode(act), raw=False)
    del old["source"], old["correction"]
    back = decode("action", msgpack.packb(old), dims=D)
    assert isinstance(back, Action) and (back.source, back.correction) == ("", False)
    for field_name, value, reason in (("source", "someone", "bad_value"),
                                      ("correction", 1, "wrong_type")):
        with pytest.raises(ProtocolError) as err:
            decode("action", msgpack.packb(dict(old, **{field_name: value})), dims=D)
        assert err.value.reason == reason


def test_stamp_prediction_gives_the_bytes_of_decode_replace_encode() -> None:
    """A worker's encoded prediction stamped in place (the daemon's publish path) is byte for
    byte what decoding it, replacing the publish-time fields and encoding again gives."""
    from protocols.messages import stamp_prediction

    dims = Dims(3, 2)
    expert = ExpertOutput(expert=4, p=0.75, mean=np.array([0.5, -1.0]),
                          var=np.array([0.1, 0.2]), n=12, label="aim")
    worker = Prediction("r3", 17, 0.5, stamp_ns=11, mean=np.array([0.25, 2.0]),
                        var=np.array([0.3, 0.4]), expert=4, multimap=(expert,), updates=99)
    payload = encode(worker)
    stamped = stamp_prediction(payload, robot="r3", tick=17, latency_ms=2.5, mode="predict",
                               stamp_ns=123456789)
    msg = decode("prediction", payload, dims=dims, robot="r3")
    assert stamped == encode(dataclasses.replace(msg, latency_ms=2.5, mode="predict",
                                                 stamp_ns=123456789))
    again = decode("prediction", stamped, dims=dims, robot="r3")
    assert isinstance(again, Prediction)
    assert (again.latency_ms, again.mode, again.stamp_ns, again.updates) == \
        (2.5, "predict", 123456789, 99)
    with pytest.raises(ValueError, match="r3 tick 18"):
        stamp_prediction(payload, robot="r3", tick=18, latency_ms=1.0, mode="predict",
                         stamp_ns=1)
    with pytest.raises(ValueError, match="r2 tick 17"):
        stamp_prediction(payload, robot="r2", tick=17, latency_ms=1.0, mode="predict",
                         stamp_ns=1)
    with pytest.raises(ValueError, match="mode"):
        stamp_prediction(payload, robot="r3", tick=17, latency_ms=1.0, mode="fly", stamp_ns=1)
    perception = encode(Perception("r3", 17, 0.5, x=np.zeros(3)))
    with pytest.raises(ValueError, match="not the prediction"):
        stamp_prediction(perception, robot="r3", tick=17, latency_ms=1.0, mode="predict",
                         stamp_ns=1)
    for bad in (payload[:-3], payload + b"\x00", b"\xc1", msgpack.packb([1, 2])):
        with pytest.raises(ValueError, match="not the prediction"):
            stamp_prediction(bad, robot="r3", tick=17, latency_ms=1.0, mode="predict",
                             stamp_ns=1)


_finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(st.integers(0, 4), st.integers(1, 4), _finite, st.integers(-1, 10**6),
       st.sampled_from(MODES), st.integers(0, 2**40), st.booleans())
def test_encode_prediction_gives_the_bytes_of_encoding_the_dataclass(
        n_experts: int, d_y: int, value: float, tick: int, mode: str, stamp: int,
        rows_as_lists: bool) -> None:
    """The workers' prediction encoder (no dataclasses) writes what ``encode(Prediction)``
    writes, byte for byte: both go through the same field maps. A row's vectors may be
    arrays or, as a daemon's worker gives them, lists of floats."""
    from protocols.messages import encode_prediction

    rng = np.random.default_rng(n_experts * 7 + d_y)
    rows = [(e - 1, float(rng.random()), rng.normal(size=d_y) * value, rng.random(d_y) + 0.1,
             int(rng.integers(0, 50)), ["", "seek", "kick"][e % 3]) for e in range(n_experts)]
    mean, var = np.full(d_y, value), np.full(d_y, 0.5)
    given = [(e, p, m.tolist(), v.tolist(), n, label) for e, p, m, v, n, label in rows] \
        if rows_as_lists else rows
    fast = encode_prediction("r1", tick, tick / 30, mean=mean, var=var, expert=n_experts - 2,
                             multimap=given, updates=tick + 1, mode=mode, latency_ms=1.5,
                             stamp_ns=stamp)
    slow = encode(Prediction("r1", tick, tick / 30, stamp_ns=stamp, mean=mean, var=var,
                             expert=n_experts - 2,
                             multimap=tuple(ExpertOutput(*row) for row in rows),
                             latency_ms=1.5, mode=mode, updates=tick + 1))
    assert fast == slow


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=12),
       st.sampled_from(["1d", "2d", "list", "float32", "int", "view", "int list",
                        "numpy floats"]))
def test_float_lists_are_what_numpy_gives_on_every_path(values: list[float], form: str) -> None:
    """``message_types._float_list`` (the encoder's vectors; fast paths for 1-D float64
    arrays and lists of floats) packs to the bytes of ``np.asarray(v, float64).reshape(-1)
    .tolist()`` whatever form the vector comes in (NaN and signed zeros included)."""
    from protocols.message_types import _float_list

    a = np.array(values, dtype=np.float64)
    given_as: object = {
        "1d": lambda: a, "2d": lambda: a.reshape(-1, 1), "list": lambda: values,
        "float32": lambda: a.clip(-1e30, 1e30).astype(np.float32),
        "int": lambda: np.nan_to_num(a).clip(-1e9, 1e9).astype(int),
        "view": lambda: np.concatenate([a, a])[::2],
        "int list": lambda: np.nan_to_num(a).clip(-1e9, 1e9).astype(int).tolist(),
        "numpy floats": lambda: list(a),
    }[form]()
    want = np.asarray(given_as, dtype=np.float64).reshape(-1).tolist()
    got = _float_list(given_as)
    assert all(type(v) is float for v in got)
    assert msgpack.packb(got) == msgpack.packb(want)

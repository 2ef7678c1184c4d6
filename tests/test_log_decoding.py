"""Logs other tools can read: mcap's own reader decodes every message with the shipped
msgpack DecoderFactory, and the JSON export names the vectors' fields (issue 56)."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import msgpack
import pytest
from mcap.exceptions import DecoderNotFoundError
from mcap.reader import make_reader

from protocols import aibo
from roger_daemon.cli import main as roger
from roger_daemon.recording.decoder import DecoderFactory, decode_msgpack

SESSIONS = sorted((Path(__file__).parent / "data" / "sessions").glob("*.mcap"))


@pytest.mark.parametrize("path", SESSIONS, ids=lambda p: p.stem)
def test_mcap_decodes_every_message_of_a_recording_with_the_shipped_factory(path: Path) -> None:
    with path.open("rb") as f:
        with pytest.raises(DecoderNotFoundError):  # what a user got before
            next(iter(make_reader(f).iter_decoded_messages()))
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    total = summary.statistics.message_count
    n = 0
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, value in reader.iter_decoded_messages():
            assert value == msgpack.unpackb(message.data, raw=False)  # the recorded bytes
            assert value["robot"] == "aibo" and isinstance(value["tick"], int)
            if channel.topic.endswith("/perception"):
                assert len(value["x"]) == 23
            n += 1
    assert n == total > 1000


def test_the_decoder_refuses_what_is_not_msgpack_and_extension_types() -> None:
    with pytest.raises(ValueError, match="not a msgpack payload"):
        decode_msgpack(b"\xc1")  # a byte msgpack never uses
    with pytest.raises(ValueError, match="extension type 5"):
        decode_msgpack(msgpack.packb(msgpack.ExtType(5, b"x")))
    assert DecoderFactory().decoder_for("json", None) is None


def test_json_export_names_the_fields_and_its_schemas_validate(tmp_path: Path) -> None:
    out = tmp_path / "named.mcap"
    assert roger(["log", "export", str(SESSIONS[0]), "--format", "json",
                  "--out", str(out)]) == 0
    seen: set[str] = set()
    validated: dict[str, int] = {}
    with out.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert channel.message_encoding == "json" and schema is not None
            value = json.loads(message.data)
            if validated.get(channel.topic, 0) < 5:  # a few per channel: validation is slow
                jsonschema.validate(value, json.loads(schema.data))
                validated[channel.topic] = validated.get(channel.topic, 0) + 1
            kind = channel.topic.rsplit("/", 1)[1]
            if kind == "perception":
                named = value["named"]["x"]
                assert list(named) == list(aibo.PERCEPTION_NAMES)
                assert named["ball_size"] == value["x"][2]
            elif kind in ("action", "command"):
                assert list(value["named"]["y"]) == list(aibo.ACTION_NAMES)
            elif kind == "prediction":
                assert value["named"]["mean"]["walk_turn"] == value["mean"][2]
                assert set(value["named"]) == {"mean", "var"}
            else:
                assert "named" not in value
            seen.add(kind)
    assert {"perception", "action", "command", "prediction", "status", "episode"} <= seen


def test_the_documented_recording_size_matches_the_shipped_sessions() -> None:
    """docs/logs.md's MB per 10 minutes at 30 Hz (the README said 9 MB, ~3x low)."""
    import re

    doc = (Path(__file__).parents[1] / "docs" / "logs.md").read_text(encoding="utf-8")
    documented = float(re.search(r"About \*\*(\d+) MB per 10 minutes", doc).group(1))
    for path in SESSIONS:
        with path.open("rb") as f:
            reader = make_reader(f)
            ticks = {m.sequence for _s, c, m in reader.iter_messages()
                     if c.topic.endswith("/perception")}
        per_10_min = path.stat().st_size / len(ticks) * 30 * 600 / 1e6
        assert 0.8 * documented <= per_10_min <= 1.25 * documented, per_10_min

"""roger log recover / info / export on real MCAP files."""

from __future__ import annotations

import json
import random
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_testing import chunk_ends, messages

from protocols import Action, Perception, Prediction, decode, encode, keys
from roger_daemon.cli import main as roger
from roger_daemon.recording import SessionRecorder, is_complete, recover, recover_in_place
from roger_daemon.recording.export import export_json, to_json_value
from roger_daemon.recording.info import format_info, log_info
from roger_daemon.recording.mcapio import read_metadata

T0 = 1_795_000_000_000_000_000
TICK = 33_333_333


def _session(path: Path, *, ticks: int = 300, chunk_size: int = 1500,
             meta: dict[str, str] | None = None) -> Path:
    """A file with many small chunks: perception every tick, action every third tick,
    a prediction every 10th tick."""
    rec = SessionRecorder(path, robot="aibo", metadata=meta or {"robot": "aibo", "seed": "3"},
                          chunk_size=chunk_size, start_ns=T0)
    for t in range(ticks):
        if 40 <= t < 50:
            continue  # a gap in the perception and action channels
        now = T0 + t * TICK
        rec.write(keys.perception("aibo"),
                  encode(Perception("aibo", t, t / 30, x=np.full(23, t / 7), stamp_ns=now - 900)),
                  log_time_ns=now, publish_time_ns=now - 900, sequence=t)
        if t % 3 == 0:
            rec.write(keys.action("aibo"),
                      encode(Action("aibo", t, t / 30, y=np.full(9, -t), label="seek",
                                    stamp_ns=now)),
                      log_time_ns=now + 500, publish_time_ns=now, sequence=t)
        if t % 10 == 0:
            rec.write(keys.prediction("aibo"),
                      encode(Prediction("aibo", t, t / 30, mean=np.zeros(9), var=np.ones(9),
                                        expert=-1, updates=t // 3, stamp_ns=now)),
                      log_time_ns=now + 700, publish_time_ns=now, sequence=t)
    rec.close()
    return rec.path


# -- recover ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def session_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _session(tmp_path_factory.mktemp("log"))


def test_recover_truncated_at_random_points_keeps_every_complete_chunk(
    session_file: Path, tmp_path: Path
) -> None:
    data = session_file.read_bytes()
    full = messages(session_file)
    ends = chunk_ends(session_file)
    assert len(ends) > 20
    rnd = random.Random(1234)
    points = [rnd.randrange(200, len(data)) for _ in range(40)]
    points += [e for e, _ in ends[:5]] + [e - 1 for e, _ in ends[:5]] + [len(data) - 1]
    for p in points:
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[:p])
        rep = recover(cut, tmp_path / "rec.mcap")
        expected = sum(n for e, n in ends if e <= p)
        assert rep.messages == expected, p
        assert messages(Path(rep.output)) == full[:expected], p
        assert is_complete(rep.output) and rep.metadata == 1
        assert not rep.complete


def test_recover_complete_file_keeps_all(session_file: Path, tmp_path: Path) -> None:
    rep = recover(session_file, tmp_path / "same.mcap")
    assert rep.complete and rep.error == "" and rep.bytes_dropped == 0
    assert messages(Path(rep.output)) == messages(session_file)


def test_recover_stops_at_a_corrupt_chunk(session_file: Path, tmp_path: Path) -> None:
    ends = chunk_ends(session_file)
    data = bytearray(session_file.read_bytes())
    start_of_5th = ends[4][0]  # the 6th chunk starts here (message indexes first, then it)
    bad = ends[5][0] - 40  # inside the 6th chunk's compressed data
    assert bad > start_of_5th
    data[bad] ^= 0xFF
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(bytes(data))
    rep = recover(broken, tmp_path / "rec.mcap")
    assert rep.messages == sum(n for _, n in ends[:5])
    assert "chunk" in rep.error or "unreadable" in rep.error


def test_recover_zero_filled_tail(session_file: Path, tmp_path: Path) -> None:
    ends = chunk_ends(session_file)
    data = session_file.read_bytes()[: ends[9][0]] + bytes(4096)
    f = tmp_path / "zeros.mcap"
    f.write_bytes(data)
    assert recover(f, tmp_path / "r.mcap").messages == sum(n for _, n in ends[:10])


def test_recover_rejects_non_mcap(tmp_path: Path) -> None:
    f = tmp_path / "x.mcap"
    f.write_bytes(b"hello world, not an mcap file")
    with pytest.raises(ValueError, match="not an MCAP"):
        recover(f)
    assert not (tmp_path / "x.recovered.mcap").exists()
    assert roger(["log", "recover", str(f)]) == 1


def test_recover_in_place_and_cli_exit_codes(session_file: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    data = session_file.read_bytes()
    cut = tmp_path / "roger-aibo-20261118T110640Z.mcap"
    cut.write_bytes(data[: len(data) // 2])
    assert roger(["log", "recover", str(cut)]) == 3  # lossy
    out = capsys.readouterr().out
    assert "kept" in out and (tmp_path / "roger-aibo-20261118T110640Z.recovered.mcap").exists()
    rep = recover_in_place(cut)
    assert is_complete(cut) and rep.output == str(cut)
    assert roger(["log", "recover", str(cut), "--out", str(tmp_path / "o.mcap"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["complete"] is True


# -- info ------------------------------------------------------------------------------------

GOLDEN_INFO = """\
file:      FILE
bytes:     SIZE
complete:  yes (footer, summary, indexes)
start:     2026-11-18T11:06:40.000Z
end:       2026-11-18T11:06:49.966Z
duration:  9.967 s
messages:  440 in CHUNKS chunks
channels:
  topic                  schema            enc      msgs  rate Hz  max gap s     seq
  roger/aibo/perception  roger.perception  msgpack   290    29.00      0.367  0..299
  roger/aibo/action      roger.action      msgpack    97     9.70      0.400  0..297
  roger/aibo/prediction  roger.prediction  msgpack    29     2.90      0.667  0..290
  roger/aibo/status      roger.status      msgpack    24     2.40      0.800  0..288
metadata roger.session:
  config: [learner] ... (2 lines)
  part: 0
  recorder: flush_interval_s=1 chunk_size=1048576 compression=zstd
  robot: aibo
  seed: 3
  session_id: roger-aibo-20261118T110640Z
  start_ns: 1795000000000000000
  start_time_utc: 2026-11-18T11:06:40Z"""


def _info_file(tmp_path: Path) -> Path:
    from protocols import Status

    rec = SessionRecorder(tmp_path, robot="aibo", start_ns=T0, chunk_size=1 << 20,
                          metadata={"robot": "aibo", "seed": "3",
                                    "config": "[learner]\nalpha = 0.5\n"})
    for t in range(300):
        if 40 <= t < 50:
            continue
        now = T0 + t * TICK
        rec.write(keys.perception("aibo"), encode(Perception("aibo", t, 0.0, x=[t])),
                  log_time_ns=now, publish_time_ns=now, sequence=t)
        if t % 3 == 0:
            rec.write(keys.action("aibo"), encode(Action("aibo", t, 0.0, y=[t])),
                      log_time_ns=now + 1, publish_time_ns=now, sequence=t)
        if t % 10 == 0:
            rec.write(keys.prediction("aibo"),
                      encode(Prediction("aibo", t, 0.0, mean=[0.0], var=[1.0], expert=-1)),
                      log_time_ns=now + 2, publish_time_ns=now, sequence=t)
        if t % 12 == 0:
            rec.write(keys.status("aibo"),
                      encode(Status("aibo", t, 0.0, daemon="d", mode="learn", ticks=t,
                                    updates=t, updates_per_s=30.0, experts=1, queue_depth=0,
                                    dropped=0)),
                      log_time_ns=now + 3, publish_time_ns=now, sequence=t)
        rec.poll(now)
    rec.close()
    return rec.path


def test_log_info_text_is_stable(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _info_file(tmp_path)
    assert roger(["log", "info", str(path)]) == 0
    text = capsys.readouterr().out.rstrip("\n")
    assert roger(["log", "info", str(path)]) == 0
    assert capsys.readouterr().out.rstrip("\n") == text
    info = log_info(path)
    lines = [ln for ln in text.splitlines() if not ln.startswith("library:")]
    normal = "\n".join(lines).replace(str(path), "FILE").replace(
        f"bytes:     {info['bytes']}", "bytes:     SIZE").replace(
        f"in {info['chunks']} chunks", "in CHUNKS chunks")
    assert normal == GOLDEN_INFO


def test_log_info_json_counts_rates_gaps(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    path = _info_file(tmp_path)
    assert roger(["log", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["complete"] and info["messages"] == 440
    perc = info["channels"][0]
    assert perc["topic"] == "roger/aibo/perception" and perc["messages"] == 290
    assert perc["max_gap_s"] == pytest.approx(11 * TICK / 1e9, abs=1e-6)
    assert perc["max_gap_after_ns"] == T0 + 39 * TICK
    assert info["metadata"]["roger.session"]["seed"] == "3"
    assert info["duration_s"] == pytest.approx((299 * TICK) / 1e9, abs=1e-6)


def test_log_info_on_a_footerless_file(session_file: Path, tmp_path: Path) -> None:
    data = session_file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    info = log_info(cut)
    assert not info["complete"] and 0 < info["messages"] < log_info(session_file)["messages"]
    assert "NO:" in format_info(info)


# -- export ----------------------------------------------------------------------------------


def test_export_is_json_with_schemas_that_validate(session_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "session.json.mcap"
    assert roger(["log", "export", str(session_file), "--out", str(out)]) == 0
    orig = messages(session_file)
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        rows = list(reader.iter_messages(log_time_order=False))
        metas = list(reader.iter_metadata())
    assert len(rows) == len(orig)
    assert [m.metadata for m in metas] == [read_metadata(session_file)]
    validators: dict[int, jsonschema.protocols.Validator] = {}
    for (schema, channel, msg), (topic, lt, pt, seq, payload) in zip(rows, orig, strict=True):
        assert channel.message_encoding == "json"
        assert schema is not None and schema.encoding == "jsonschema"
        assert (channel.topic, msg.log_time, msg.publish_time, msg.sequence) == (topic, lt, pt,
                                                                                 seq)
        v = validators.get(schema.id)
        if v is None:
            sch = json.loads(schema.data)
            jsonschema.Draft202012Validator.check_schema(sch)
            v = validators[schema.id] = jsonschema.Draft202012Validator(sch)
        value = json.loads(msg.data)
        v.validate(value)
        kind = topic.rsplit("/", 1)[1]
        assert decode(kind, encode_json_back(value)).to_map() == decode(kind, payload).to_map()


def encode_json_back(value: dict[str, object]) -> bytes:
    import msgpack

    out: bytes = msgpack.packb(value, use_bin_type=True)
    return out


def test_export_counts_non_msgpack_payloads(tmp_path: Path) -> None:
    with SessionRecorder(tmp_path, robot="aibo", metadata={}, start_ns=T0) as rec:
        rec.write("roger/aibo/perception", b"\xc1", log_time_ns=1, publish_time_ns=1, sequence=0)
        rec.write("roger/aibo/perception", encode(Perception("aibo", 1, 0.0, x=[1.0])),
                  log_time_ns=2, publish_time_ns=2, sequence=1)
        rec.write("misc/raw", b"\x92\x01\xc4\x02ab", log_time_ns=3, publish_time_ns=3, sequence=0)
    rep = export_json(rec.path, tmp_path / "out.mcap")
    assert rep.messages == 2 and rep.skipped == {"roger/aibo/perception": 1}
    with open(tmp_path / "out.mcap", "rb") as f:
        rows = list(make_reader(f).iter_messages(log_time_order=False))
    assert rows[1][0] is None and json.loads(rows[1][2].data) == [1, "YWI="]
    assert to_json_value({"a": float("nan"), "b": b"\x00"}) == {"a": None, "b": "AA=="}


def test_recover_directory_fixes_only_damaged_session_files(session_file: Path,
                                                            tmp_path: Path) -> None:
    from roger_daemon.recording import recover_directory

    data = session_file.read_bytes()
    good = tmp_path / "roger-aibo-20261118T110640Z.mcap"
    cut = tmp_path / "roger-aibo-20261118T110641Z.mcap"
    empty = tmp_path / "roger-aibo-20261118T110642Z.mcap"
    good.write_bytes(data)
    cut.write_bytes(data[: len(data) // 3])
    empty.write_bytes(b"")
    reps = recover_directory(tmp_path)
    assert [Path(r.source).name for r in reps] == [cut.name, empty.name]
    assert reps[0].messages > 0 and reps[1].messages == 0
    assert is_complete(good) and is_complete(cut) and not empty.exists()
    assert (tmp_path / (cut.name + ".damaged")).read_bytes() == data[: len(data) // 3]
    assert (tmp_path / (empty.name + ".damaged")).exists()
    assert recover_directory(tmp_path) == []

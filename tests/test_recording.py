"""SessionRecorder: round trip, schemas, metadata, rotation, the flush bound, SIGKILL."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import jsonschema
import msgpack
import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader

from protocols import (
    Action,
    Command,
    Control,
    EpisodeEvent,
    ExpertOutput,
    Perception,
    Prediction,
    Status,
    encode,
    keys,
)
from protocols.decisions import (
    Dropped,
    Learned,
    ModelDigest,
    Reset,
    chain_digest,
    decode_decision,
)
from protocols.errors import ProtocolError
from protocols.keys import KINDS
from protocols.messages import Dims
from roger_daemon.recording import (
    METADATA_NAME,
    SessionInfo,
    SessionRecorder,
    header_fields,
    is_complete,
    list_session_files,
    parse_name,
    recover,
    schema,
    schema_bytes,
    schema_name,
    session_metadata,
)
from roger_daemon.recording.files import group_sessions
from roger_daemon.recording.mcapio import LogReader, read_metadata

T0 = 1_795_000_000_000_000_000
TICK = 33_333_333


def _samples() -> dict[str, object]:
    mm = (ExpertOutput(expert=3, p=0.75, mean=np.ones(9), var=np.full(9, 0.5), n=12, label="aim"),
          ExpertOutput(expert=-1, p=0.25, mean=np.zeros(9), var=np.ones(9), n=0))
    return {
        "perception": Perception("aibo", 4, 0.13, x=np.linspace(-1, 1, 23), stamp_ns=T0),
        "action": Action("aibo", 4, 0.13, y=np.arange(9.0), label="seek", stamp_ns=T0),
        "command": Command("aibo", 4, 0.13, y=np.arange(9.0), source="hcc", stamp_ns=T0),
        "prediction": Prediction("aibo", 4, 0.13, mean=np.ones(9), var=np.ones(9), expert=3,
                                 multimap=mm, latency_ms=2.5, mode="learn", updates=17,
                                 stamp_ns=T0),
        "episode": EpisodeEvent("aibo", 4, 0.13, event="goal", episode=2, data={"x": 1.5},
                                stamp_ns=T0),
        "status": Status("aibo", 4, 0.13, daemon="d1", mode="pause", ticks=4, updates=3,
                         updates_per_s=29.5, experts=2, queue_depth=0, dropped=1,
                         invalid={"not_finite": 2}, info={"host": "x"}, stamp_ns=T0),
        "control": Control("aibo", 4, 0.13, op="mode", mode="predict", stamp_ns=T0),
    }


def _meta(**over: object) -> dict[str, str]:
    return session_metadata(robot="aibo", config_text="[learner]\nalpha = 0.5\n",
                            learner_params={"alpha": 0.5}, dims=(23, 9), seed=11,
                            **over)  # type: ignore[arg-type]


def _write_ticks(rec: SessionRecorder, ticks: range, robot: str = "aibo") -> None:
    for t in ticks:
        now = T0 + t * TICK
        rec.write(keys.perception(robot), encode(Perception(robot, t, t / 30, x=np.full(23, t),
                                                            stamp_ns=now - 5)),
                  log_time_ns=now, publish_time_ns=now - 5, sequence=t)
        rec.write(keys.action(robot), encode(Action(robot, t, t / 30, y=np.full(9, t),
                                                    label="seek", stamp_ns=now - 7)),
                  log_time_ns=now + 1, publish_time_ns=now - 7, sequence=t)


def _salvage(data: bytes) -> list[tuple[str, int]]:
    """(topic, sequence) of every message NonSeekingReader gets out of a (partial) file."""
    out = []
    try:
        for _, ch, msg in NonSeekingReader(io.BytesIO(data)).iter_messages(log_time_order=False):
            out.append((ch.topic, msg.sequence))
    except McapError:
        pass
    return out


# -- schemas ---------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_schema_matches_protocol_fields_and_validates(kind: str) -> None:
    msg = _samples()[kind]
    sch = schema(kind)
    jsonschema.Draft202012Validator.check_schema(sch)
    m = msgpack.unpackb(encode(msg), raw=False)  # type: ignore[arg-type]
    assert set(sch["properties"]) == set(m) == set(sch["required"])
    jsonschema.validate(m, sch)
    assert json.loads(schema_bytes(kind)) == sch


def test_schema_rejects_wrong_payloads() -> None:
    m = msgpack.unpackb(encode(_samples()["prediction"]), raw=False)  # type: ignore[arg-type]
    bad = dict(m, var=[0.0] * 9)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema("prediction"))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(dict(m, extra=1), schema("prediction"))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(dict(m, mode="sleep"), schema("prediction"))


def test_schema_bytes_are_pinned() -> None:
    """The schemas are generated from the message classes' fields; their bytes are those of
    every MCAP file written so far (tests/data/schemas.json), byte for byte, kind by kind."""
    golden = json.loads((Path(__file__).parent / "data" / "schemas.json").read_text("utf-8"))
    assert sorted(golden) == sorted(KINDS)
    for kind in KINDS:
        assert schema_bytes(kind) == golden[kind].encode("utf-8"), kind


def _decision_records() -> dict[str, object]:
    return {
        "learned": Learned("aibo", 4, 0.13, updates=5, segment=0, x=np.linspace(-1, 1, 23),
                           y=np.arange(9.0), label="seek", stamp_ns=T0),
        "reset": Reset("aibo", 4, 0.13, segment=1, forgotten=5, stamp_ns=T0),
        "dropped": Dropped("aibo", 4, 0.13, reason="queue_full", queue_size=256, dropped=3,
                           stamp_ns=T0),
        "model": ModelDigest("aibo", 4, 0.13, updates=5, segment=0, digest="a" * 64,
                             chain=chain_digest("", "a" * 64), stamp_ns=T0),
    }


@pytest.mark.parametrize("event", keys.DECISIONS)
def test_decision_records_have_generated_schemas_and_decode(event: str) -> None:
    """The daemon's decision records (protocols/decisions.py) get their schemas generated from
    their fields like the wire's messages, and decode back to what was encoded."""
    rec = _decision_records()[event]
    sch = schema(f"daemon.{event}")
    jsonschema.Draft202012Validator.check_schema(sch)
    m = msgpack.unpackb(encode(rec), raw=False)  # type: ignore[arg-type]
    assert set(sch["properties"]) == set(m) == set(sch["required"])
    jsonschema.validate(m, sch)
    assert decode_decision(event, encode(rec), dims=Dims(23, 9)).to_map() == m  # type: ignore[arg-type]
    with pytest.raises(ProtocolError):
        decode_decision(event, msgpack.packb({**m, "tick": -1}))
    with pytest.raises(ProtocolError):
        decode_decision(event, msgpack.packb({k: v for k, v in m.items() if k != "robot"}))
    assert keys.parse_decision(keys.decision("aibo", event)) == ("aibo", event)
    assert schema_name(f"daemon.{event}") == f"roger.daemon.{event}"  # as older logs name it


# -- metadata --------------------------------------------------------------------------------


def test_session_metadata_has_config_params_dims_seed_versions() -> None:
    m = _meta(mode="learn", start_updates=40, checkpoint="ck.npz", extra={"note": "x"})
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in m.items())
    for k in ("roger_version", "numpy_version", "scipy_version", "zenoh_version",
              "mcap_version", "msgpack_version", "python_version", "git_commit", "hostname"):
        assert k in m
    assert m["numpy_version"] == np.__version__
    assert m["config"].startswith("[learner]")
    # which BLAS computed: library, kernel and thread count (one thread: roger_daemon/blas.py)
    blas = json.loads(m["blas"])
    assert blas and all(b["threads"] == 1 and b["library"] and b["kernel"] for b in blas)
    info = SessionInfo.from_metadata(m)
    assert (info.robot, info.seed, info.mode, info.start_updates) == ("aibo", 11, "learn", 40)
    assert info.dims is not None and (info.dims.x, info.dims.y) == (23, 9)
    assert info.learner_params == {"alpha": 0.5}
    assert m["note"] == "x"
    with pytest.raises(ValueError, match="collides"):
        _meta(extra={"seed": "1"})
    with pytest.raises(ValueError, match="mode"):
        _meta(mode="fly")


def test_the_format_version_says_whether_the_daemon_recorded_its_decisions() -> None:
    v2 = SessionInfo.from_metadata(session_metadata(robot="r", decisions=True))
    assert v2.format_version == 2 and v2.decisions  # the daemon's logs
    v1 = SessionInfo.from_metadata(session_metadata(robot="r"))  # roger record, hand-made
    assert v1.format_version == 1 and not v1.decisions
    assert SessionInfo.from_metadata({}).format_version == 1  # logs older than the key


def test_session_metadata_takes_params_objects() -> None:
    class P:
        def to_mapping(self) -> dict[str, object]:
            return {"beta": 300, "alpha": 0.5}

    m = session_metadata(robot="r", learner_params=P())
    assert json.loads(m["learner_params"]) == {"alpha": 0.5, "beta": 300}
    assert SessionInfo.from_metadata({}).seed is None


# -- writer round trip -----------------------------------------------------------------------


def test_round_trip_channels_schemas_metadata_times(tmp_path: Path) -> None:
    samples = _samples()
    rec = SessionRecorder(tmp_path, robot="aibo", metadata=_meta(), start_ns=T0)
    written = []
    for i, kind in enumerate(KINDS * 3):
        payload = encode(samples[kind])  # type: ignore[arg-type]
        key = keys.key("aibo", kind)
        rec.write(key, payload, log_time_ns=T0 + i * 1000, publish_time_ns=T0 + i * 1000 - 3,
                  sequence=100 + i)
        written.append((key, payload, T0 + i * 1000, T0 + i * 1000 - 3, 100 + i))
    rec.write("other/thing", b"raw", log_time_ns=T0 + 10**6, publish_time_ns=0, sequence=0)
    rec.close()
    rec.close()  # idempotent
    assert rec.path.name == "roger-aibo-20261118T110640Z.mcap"
    assert is_complete(rec.path)
    with open(rec.path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(written) + 1
        assert len(summary.channels) == len(KINDS) + 1
        by_topic = {c.topic: c for c in summary.channels.values()}
        for kind in KINDS:
            ch = by_topic[keys.key("aibo", kind)]
            assert ch.message_encoding == "msgpack"
            assert ch.metadata == {"robot": "aibo", "kind": kind}
            s = summary.schemas[ch.schema_id]
            assert (s.name, s.encoding, s.data) == (f"roger.{kind}", "jsonschema",
                                                    schema_bytes(kind))
        assert by_topic["other/thing"].schema_id == 0
        got = [(c.topic, m.data, m.log_time, m.publish_time, m.sequence)
               for _, c, m in reader.iter_messages(log_time_order=False)]
        assert got[:-1] == written
        metas = list(reader.iter_metadata())
    assert [m.name for m in metas] == [METADATA_NAME]
    md = metas[0].metadata
    assert md["session_id"] == "roger-aibo-20261118T110640Z" and md["part"] == "0"
    assert md["seed"] == "11" and md["start_ns"] == str(T0)
    assert read_metadata(rec.path) == md
    with pytest.raises(RuntimeError):
        rec.write("roger/aibo/perception", b"", log_time_ns=0, publish_time_ns=0, sequence=0)


def test_recorder_rejects_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(TypeError):
        SessionRecorder(tmp_path, robot="a", metadata={"seed": 1})  # type: ignore[dict-item]
    with pytest.raises(ValueError):
        SessionRecorder(tmp_path, robot="a", metadata={}, compression="gzip")
    with pytest.raises(ValueError):
        SessionRecorder(tmp_path, robot="bad/id", metadata={})


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compressions_read_back(tmp_path: Path, compression: str) -> None:
    with SessionRecorder(tmp_path, robot="aibo", metadata={}, compression=compression,
                         start_ns=T0) as rec:
        _write_ticks(rec, range(50))
    reader = LogReader(rec.path)
    assert len(list(reader.messages())) == 100 and reader.complete


def test_two_sessions_in_one_second_get_distinct_names(tmp_path: Path) -> None:
    a = SessionRecorder(tmp_path, robot="aibo", metadata={}, start_ns=T0)
    b = SessionRecorder(tmp_path, robot="aibo", metadata={}, start_ns=T0 + 10)
    a.close()
    b.close()
    assert a.session_id != b.session_id and b.session_id.endswith("_2")
    assert [f.path for f in list_session_files(tmp_path)] == [a.path, b.path]


# -- rotation --------------------------------------------------------------------------------


def test_rotation_by_size_keeps_every_message_in_order(tmp_path: Path) -> None:
    rec = SessionRecorder(tmp_path, robot="aibo", metadata=_meta(), rotate_bytes=20_000,
                          rotate_s=None, start_ns=T0)
    for t in range(0, 600, 10):
        _write_ticks(rec, range(t, t + 10))
        rec.poll(T0 + (t + 10) * TICK)
    rec.close()
    parts = rec.paths
    assert len(parts) >= 3
    assert [p.name for p in parts[:3]] == [
        "roger-aibo-20261118T110640Z.mcap",
        "roger-aibo-20261118T110640Z-001.mcap",
        "roger-aibo-20261118T110640Z-002.mcap",
    ]
    found = list_session_files(tmp_path, robot="aibo")
    assert [f.path for f in found] == parts
    assert len(group_sessions(found)) == 1
    seqs = []
    for i, p in enumerate(parts):
        assert is_complete(p)
        meta = read_metadata(p)
        assert meta["part"] == str(i) and meta["seed"] == "11"
        r = LogReader(p)
        seqs += [lm.message.sequence for lm in r.messages() if lm.topic.endswith("perception")]
    assert seqs == list(range(600))


def test_rotation_by_time(tmp_path: Path) -> None:
    rec = SessionRecorder(tmp_path, robot="aibo", metadata={}, rotate_bytes=None, rotate_s=10.0,
                          start_ns=T0)
    rec.poll(0)
    for t in range(0, 30 * 35):  # 35 s at 30 Hz
        _write_ticks(rec, range(t, t + 1))
        rec.poll(t * TICK)
    rec.close()
    assert len(rec.paths) == 4  # rotations at 10, 20, 30 s
    total = sum(len(list(LogReader(p).messages())) for p in rec.paths)
    assert total == 2 * 30 * 35


def test_rotation_releases_the_finished_parts_chunk_index(tmp_path: Path) -> None:
    """The MCAP writer keeps one index entry per chunk until its file is finished (for the
    summary): with a chunk a second per robot that is what grows in the daemon's loop process
    over an hour (docs/fleet.md). Rotation must drop the finished part's writer, so that the
    growth is bounded by ``rotate_s``."""
    import gc
    import weakref

    rec = SessionRecorder(tmp_path, robot="aibo", metadata={}, rotate_bytes=None, rotate_s=10.0,
                          flush_interval_s=1.0, start_ns=T0)
    rec.poll(0)
    first = weakref.ref(rec._writer)
    for t in range(0, 30 * 15):  # 15 s at 30 Hz: a flushed chunk every second, one rotation
        _write_ticks(rec, range(t, t + 1))
        rec.poll(t * TICK)
    gc.collect()
    assert len(rec.paths) == 2
    assert first() is None  # the first part's writer and its chunk indexes are gone
    rec.close()


def test_parse_name() -> None:
    sf = parse_name("/x/roger-my-bot_2-20261118T110640Z_3-012.mcap")
    assert sf is not None
    assert (sf.robot, sf.stamp, sf.k, sf.part) == ("my-bot_2", "20261118T110640Z", 3, 12)
    assert sf.session_id == "roger-my-bot_2-20261118T110640Z_3"
    assert parse_name("roger-aibo-20261118T110640Z.recovered.mcap") is None


# -- flush bound -----------------------------------------------------------------------------


def test_poll_after_flush_interval_puts_messages_on_disk(tmp_path: Path) -> None:
    """The in-process half of 'SIGKILL loses at most the flush interval'."""
    rec = SessionRecorder(tmp_path, robot="aibo", metadata=_meta(), flush_interval_s=1.0,
                          chunk_size=1 << 20, start_ns=T0)
    rec.poll(0)
    _write_ticks(rec, range(20))
    rec.poll(999_999_999)  # not yet due: the chunk is still in memory
    assert _salvage(rec.path.read_bytes()) == []
    rec.poll(1_000_000_000)  # due: chunk closed and handed to the OS
    copy = tmp_path / "copy.bin"
    shutil.copyfile(rec.path, copy)
    got = _salvage(copy.read_bytes())
    assert [s for t, s in got if t.endswith("perception")] == list(range(20))
    assert len(got) == 40
    _write_ticks(rec, range(20, 25))
    rec.poll(1_500_000_000)
    assert len(_salvage(rec.path.read_bytes())) == 40
    rec.poll(2_000_000_000)
    assert len(_salvage(rec.path.read_bytes())) == 50
    assert rec.stats.flushes == 2
    rec.close()


def test_flush_phase_moves_the_first_flush_only(tmp_path: Path) -> None:
    """Robot i of n flushes (i + 1)/n of an interval after the first poll, then every
    interval: n recorders never compress their chunks in the same loop cycle."""
    rec = SessionRecorder(tmp_path, robot="aibo", metadata=_meta(), flush_interval_s=1.0,
                          flush_phase=0.25, chunk_size=1 << 20, start_ns=T0)
    rec.poll(0)
    _write_ticks(rec, range(10))
    rec.poll(249_999_999)
    assert rec.stats.flushes == 0
    rec.poll(250_000_000)
    assert rec.stats.flushes == 1 and len(_salvage(rec.path.read_bytes())) == 20
    _write_ticks(rec, range(10, 15))
    rec.poll(1_249_999_999)
    assert rec.stats.flushes == 1
    rec.poll(1_250_000_000)
    assert rec.stats.flushes == 2 and len(_salvage(rec.path.read_bytes())) == 30
    rec.close()
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="flush_phase"):
            SessionRecorder(tmp_path, robot="aibo", metadata={}, flush_phase=bad)


def test_daemon_recorders_get_distinct_flush_phases(tmp_path: Path) -> None:
    from protocols.messages import Dims
    from roger_daemon.config import parse_config
    from roger_daemon.daemon.main import make_model, open_recorders
    from roger_daemon.daemon.robot import RobotRuntime

    cfg = parse_config({"recording": {"dir": str(tmp_path)},
                        "robots": [{"id": f"r{i}"} for i in range(4)]})

    robots = {r.id: RobotRuntime(r.id, Dims(r.x_dim, r.y_dim), make_model(r), lambda: None)
              for r in cfg.robots}
    recs = open_recorders(cfg, robots, {})
    try:
        phases = [rec._first_flush_ns for rec in recs.values()]  # type: ignore[attr-defined]
        assert phases == [250_000_000, 500_000_000, 750_000_000, 1_000_000_000]
    finally:
        for rec in recs.values():
            rec.close()


def test_flush_now_and_chunk_size_close_chunks(tmp_path: Path) -> None:
    rec = SessionRecorder(tmp_path, robot="aibo", metadata={}, chunk_size=2048, start_ns=T0)
    _write_ticks(rec, range(30))  # ~12 kB: several chunks closed by size
    n_size = len(_salvage(rec.path.read_bytes()))
    rec.flush()
    assert 0 < n_size <= 60 and len(_salvage(rec.path.read_bytes())) == 60
    rec.close()


@pytest.mark.integration
def test_sigkilled_writer_keeps_everything_flushed(tmp_path: Path) -> None:
    """A real writer process killed with SIGKILL: every tick it reported flushed is in the
    salvaged file, and the recovered file is valid and indexed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon.recording.crashwriter", "--out", str(tmp_path),
         "--rate", "300", "--flush-interval", "0.1"],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().split()
        assert first[0] == "file"
        flushed = [int(proc.stdout.readline().split()[1]) for _ in range(4)]
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    path = Path(first[1])
    assert not is_complete(path)
    rep = recover(path, tmp_path / "out.mcap")
    assert not rep.complete and is_complete(rep.output)
    with open(rep.output, "rb") as f:
        reader = make_reader(f)
        ticks = sorted({m.sequence for _, _, m in reader.iter_messages()})
        assert reader.get_summary().statistics.message_count == rep.messages  # type: ignore[union-attr]
    assert ticks[: flushed[-1] + 1] == list(range(flushed[-1] + 1))
    assert rep.messages >= 4 * (flushed[-1] + 1)


# -- misc ------------------------------------------------------------------------------------


def test_header_fields() -> None:
    p = encode(Perception("aibo", 9, 0.3, x=np.zeros(3), stamp_ns=123))
    assert header_fields(p) == (9, 123)
    assert header_fields(b"\xc1") is None
    assert header_fields(msgpack.packb([1, 2])) is None
    assert header_fields(msgpack.packb({"tick": -1, "stamp_ns": 1})) is None

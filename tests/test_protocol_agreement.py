"""The daemon counts what protocols/README.md says it counts, and reports the same numbers in
status and in checkpoints; a re-sent pair is not learned twice."""

from __future__ import annotations

import bisect
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

import pytest
from test_daemon_service import STREAM, Harness, make_config

from protocols import Action, Control, Perception, encode
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint


def test_garbage_on_every_kind_it_decodes_is_counted_alike_in_status_and_checkpoint(
        tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    h.send("command", b"\xc1garbage")
    h.send("episode", b"\xc1garbage")
    h.send("perception", b"\xc1garbage")
    h.transport.inject("roger/aibo", b"x")  # two chunks: a bad key, no robot to blame
    h.transport.inject("roger/aibo/nonsense", b"x")  # a bad key of a served robot
    h.settle()
    st = h.status()
    assert st.invalid == {"not_msgpack": 3, "bad_key": 2}
    h.send("control", encode(Control("aibo", 0, 0.0, op="checkpoint")))
    h.settle()
    ck = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "aibo")[0])
    assert ck.meta.counters.invalid == st.invalid
    # after a restart from that checkpoint the counts go on from there, not doubled
    h2 = Harness(make_config(tmp_path), fresh=False)
    assert h2.status().invalid == st.invalid


def test_a_re_sent_pair_is_counted_once(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    for t in (0, 1, 1, 2):  # tick 1 re-sent (its prediction was lost)
        h.send("action", encode(Action("aibo", t, t / 30, y=STREAM.y[t])))
        h.send("perception", encode(Perception("aibo", t, t / 30, x=STREAM.x[t])))
        h.settle()
    assert [p.updates for p in h.predictions()] == [1, 2, 2, 3]
    st = h.status()
    assert st.updates == 3 and st.info["resent_pairs"] == 1


def _header(**fields: object) -> dict[str, object]:
    return {"v": 1, "robot": "aibo", "tick": 0, "t": 0.0, "stamp_ns": 0, **fields}


def test_decoder_rules_match_the_document() -> None:
    import msgpack
    import pytest

    from protocols import decode
    from protocols.errors import ProtocolError

    def reason(kind: str, m: dict[str, object]) -> str:
        with pytest.raises(ProtocolError) as err:
            decode(kind, msgpack.packb(m))
        return err.value.reason

    # extension types are rejected, the zero-length ones too
    assert reason("control", _header(op="reset", z=msgpack.ExtType(1, b""))) == "not_msgpack"
    # string limits are UTF-8 bytes: 256 bytes pass, 257 are oversized, > 1024 not msgpack
    assert decode("action", msgpack.packb(_header(y=[0.0] * 9, label="é" * 128))).label
    assert reason("action", _header(y=[0.0] * 9, label="é" * 129)) == "oversized"
    assert reason("action", _header(y=[0.0] * 9, label="x" * 1025)) == "not_msgpack"
    # control: mode optional except with op = "mode"
    assert decode("control", msgpack.packb(_header(op="reset"))).op == "reset"
    assert reason("control", _header(op="mode")) == "missing_field"
    assert reason("control", _header(op="mode", mode="fly")) == "bad_value"


class _CountingWal:
    """A real write-ahead log that also counts the pairs appended and, of those, the ones
    durable now: by the log's own ``durable_seq``, which the daemon's synchronous commits and
    its background ones (``commit_early``, docs/durability.md) both advance."""

    def __init__(self, directory: Path) -> None:
        from roger_daemon.daemon.wal import WriteAheadLog

        self.wal = WriteAheadLog(directory, 0)
        self.pair_seqs: list[int] = []

    def __getattr__(self, name: str) -> object:
        return getattr(self.wal, name)

    def append_pair(self, *args: object) -> int:
        seq = int(self.wal.append_pair(*args))  # type: ignore[arg-type]
        self.pair_seqs.append(seq)
        return seq

    @property
    def durable(self) -> int:
        return bisect.bisect_right(self.pair_seqs, self.wal.durable_seq)


def _watch(h: Harness, wal: _CountingWal) -> list[tuple[str, int, int]]:
    """Wrap the daemon's publishers: (kind, updates reported, pairs durable) per publish."""
    from protocols import decode

    seen: list[tuple[str, int, int]] = []
    pubs = h.service.outbox.pubs["aibo"]
    for kind in ("prediction", "status"):
        inner = getattr(pubs, kind)

        def put(payload: bytes, inner: object = inner, kind: str = kind) -> None:
            msg = decode(kind, payload)
            seen.append((kind, int(msg.updates), wal.durable))  # type: ignore[attr-defined]
            inner.put(payload)  # type: ignore[attr-defined]

        setattr(pubs, kind, type("P", (), {"put": staticmethod(put)})())
    return seen


class _InlineExecutor(Executor):
    """Runs each job at submission: the daemon's background log commits finish at once."""

    def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Future[Any]:
        future: Future[Any] = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:
            future.set_exception(exc)
        return future


@pytest.mark.parametrize("background", ["threads", "finished at once"])
def test_nothing_is_reported_learned_before_it_is_durable(tmp_path: Path,
                                                          background: str) -> None:
    """Every prediction and status reports at most the pairs durable when it is published.
    With the background commits finished at once (as on a loaded machine, where they finish
    before the next publish), durability comes from them and not from a commit before the
    publish: the count is the log's own ``durable_seq``."""
    for clock in ("lockstep", "realtime"):
        h = Harness(make_config(tmp_path / clock, clock=clock))
        if background != "threads":
            h.service._committer = _InlineExecutor()
        wal = _CountingWal(tmp_path / clock / "wal")
        h.rt.wal = wal
        seen = _watch(h, wal)
        for t in range(25):
            h.send("perception", encode(Perception("aibo", t, t / 30, x=STREAM.x[t])))
            h.send("action", encode(Action("aibo", t, t / 30, y=STREAM.y[t])))
            for _ in range(3):
                h.clock.advance(1 / 90)
                h.service.step(0)
        h.status()
        assert seen and max(u for _, u, _ in seen) >= 20, (clock, seen[-3:])
        assert [s for s in seen if s[1] > s[2]] == [], clock
        assert {k for k, _, _ in seen} == {"prediction", "status"}

"""Hot standby (roger_daemon/daemon/standby.py, docs/daemon.md *Hot standby*) with the in-memory
transport: a primary and a standby service side by side, the primary's published decision
records relayed to the standby, tokens injected. The real-process version (kill -9 of the
primary over Zenoh) is tests/test_standby_takeover.py."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_daemon_service import LABELS, STREAM, Harness, make_config

from protocols import Action, Control, Perception, encode, keys
from roger_daemon.config import ConfigError, DaemonConfig, parse_config
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.daemon.main import make_model
from roger_daemon.daemon.wal import WriteAheadLog, wal_dir

TOKEN = keys.active_token("prim", "aibo", 0)


def pair(t: int) -> tuple[bytes, bytes]:
    return (encode(Action("aibo", t, t / 30, y=STREAM.y[t], label=LABELS[STREAM.labels[t]])),
            encode(Perception("aibo", t, t / 30, x=STREAM.x[t])))


def feed(h: Harness, t: int) -> None:
    """action(t) then perception(t): the lockstep sender's order (prediction(t) counts t+1)."""
    a, p = pair(t)
    h.send("action", a)
    h.send("perception", p)
    h.settle()


def relay(src: Harness, dst: Harness, *, skip: frozenset[int] = frozenset()) -> int:
    """Deliver ``src``'s published decision records to ``dst`` (the ``skip``-th ones lost)."""
    n = 0
    for i, (key, data) in enumerate(
            [(k, d) for k, d, _ in src.transport.published if keys.parse_replica(k)]):
        if i not in skip:
            assert dst.transport.inject(key, data) == 1
            n += 1
    src.transport.published[:] = [p for p in src.transport.published
                                  if not keys.parse_replica(p[0])]
    dst.settle()
    return n


def pair_of(tmp_path: Path) -> tuple[Harness, Harness]:
    prim = Harness(make_config(tmp_path / "p", id="prim"))
    # the primary's token is alive when the standby starts (delivered by the token watch)
    standby = _started(make_config(tmp_path / "s", id="spare", role="standby"), others=[TOKEN])
    return prim, standby


def _started(cfg: DaemonConfig, *, others: list[str], peers: tuple[Harness, ...] = (),
             wal: bool = False) -> Harness:
    """A ``Harness`` whose transport already sees ``others``' tokens (and reaches ``peers``'
    queryables) when it starts; with ``wal``, a write-ahead log in its checkpoint dir."""
    from roger_daemon.testing import MemoryTransport

    original = MemoryTransport.__init__

    def with_others(self: MemoryTransport, *a: object, **kw: object) -> None:
        original(self, *a, **kw)  # type: ignore[arg-type]
        self.others.extend(others)
        self.peers.extend(p.transport for p in peers)

    MemoryTransport.__init__ = with_others  # type: ignore[method-assign]
    try:
        return Harness(cfg, wal=new_wal(cfg) if wal else None)
    finally:
        MemoryTransport.__init__ = original  # type: ignore[method-assign]


def new_wal(cfg: DaemonConfig) -> WriteAheadLog:
    """A fresh robot's log, as the daemon starts one (wal.start with ``fresh``)."""
    log = WriteAheadLog(wal_dir(cfg.checkpoint.dir, "aibo"), 0)
    log.append_fresh()
    log.commit()
    return log


def reference_digest(h: Harness, n: int) -> str:
    ref = make_model(h.service.config.robots[0])
    for t in range(n):
        ref.learn_one(STREAM.x[t], STREAM.y[t])
    return array_digest(dict(ref.state_dict()))


def digest(h: Harness) -> str:
    return array_digest(dict(h.rt.model.state_dict()))


def test_the_role_is_validated() -> None:
    assert parse_config({"daemon": {"role": "standby"}}).role == "standby"
    assert parse_config({}).role == "primary"
    with pytest.raises(ConfigError,
                       match=r'daemon\.role must be one of "primary", "standby", got "leader"'):
        parse_config({"daemon": {"role": "leader"}})


def test_the_standby_learns_the_primarys_pairs_and_answers_nothing(tmp_path: Path) -> None:
    prim, standby = pair_of(tmp_path)
    assert keys.active_token("prim", "aibo", 0) in prim.transport.tokens
    assert not any("/active/" in k for k in standby.transport.tokens)
    for t in range(40):
        feed(prim, t)
        feed(standby, t)
        relay(prim, standby)
    assert prim.rt.updates == standby.rt.updates == 40
    assert digest(standby) == digest(prim) == reference_digest(prim, 40)
    assert standby.predictions() == [] and len(prim.predictions()) == 40
    st = standby.status()
    assert st.info["role"] == "standby" and st.info["served_by"] == "prim"
    assert st.info["standby_followed"] == 40 and st.info["standby_in_sync"]
    assert prim.status().info["role"] == "primary"


def test_takeover_serves_the_robot_with_every_pair_the_primary_may_have_acknowledged(
        tmp_path: Path) -> None:
    prim, standby = pair_of(tmp_path)
    for t in range(30):
        feed(prim, t)
        feed(standby, t)
        if t < 27:  # the records of pairs 27-29 die with the primary
            relay(prim, standby)
    acknowledged = prim.predictions()[-1].updates
    assert acknowledged == 30 and standby.rt.updates == 27
    standby.transport.token(TOKEN, alive=False)  # the primary's token goes: kill -9
    standby.settle()
    assert keys.active_token("spare", "aibo", 1) in standby.transport.tokens
    answers = standby.predictions()  # the newest perception (29) is answered at once
    assert [(p.tick, p.updates) for p in answers] == [(29, 30)]
    assert digest(standby) == reference_digest(standby, 30)
    # the sender re-sends the unanswered tick: recognised, not learned twice
    feed(standby, 29)
    assert standby.rt.updates == 30 and standby.rt.resent == 1
    feed(standby, 30)
    assert standby.predictions()[-1].updates == 31
    st = standby.status()
    assert st.info["role"] == "primary" and st.info["takeovers"] == 1
    assert st.info["takeover_tail_pairs"] == 3 and st.info["epoch"] == 1


def test_a_lost_record_is_counted_as_a_gap(tmp_path: Path) -> None:
    prim, standby = pair_of(tmp_path)
    for t in range(10):
        feed(prim, t)
    relay(prim, standby, skip=frozenset({4}))
    st = standby.status()
    assert st.info["standby_missing"] == 1 and not st.info["standby_in_sync"]


def test_a_reset_of_the_primary_resets_the_standby(tmp_path: Path) -> None:
    prim, standby = pair_of(tmp_path)
    for t in range(10):
        feed(prim, t)
    prim.send("control", encode(Control("aibo", 0, 0.0, op="reset")))
    prim.settle()
    for t in range(10, 15):
        feed(prim, t)
    relay(prim, standby)
    assert standby.rt.updates == prim.rt.updates == 5
    assert digest(standby) == digest(prim)
    assert standby.status().info["standby_in_sync"]


def test_a_primary_that_finds_another_daemon_serving_starts_as_its_standby(
        tmp_path: Path) -> None:
    """The primary returning after a takeover does not split the brain."""
    back = _started(make_config(tmp_path / "b", id="prim"),
                    others=[keys.active_token("spare", "aibo", 1)])
    assert not any("/active/" in k for k in back.transport.tokens)
    feed(back, 0)
    assert back.predictions() == []
    assert back.status().info["role"] == "standby"
    # when the daemon it follows goes, it serves in the mode it was configured with
    back.transport.token(keys.active_token("spare", "aibo", 1), alive=False)
    back.settle()
    assert [(p.tick, p.mode) for p in back.predictions()] == [(0, "learn+predict")]
    assert keys.active_token("prim", "aibo", 2) in back.transport.tokens


def test_of_two_daemons_serving_one_robot_the_lower_epoch_yields(tmp_path: Path) -> None:
    prim = Harness(make_config(tmp_path / "p", id="prim"))
    feed(prim, 0)
    assert len(prim.predictions()) == 1
    prim.transport.token(keys.active_token("other", "aibo", 1), alive=True)
    prim.settle()
    assert TOKEN not in prim.transport.tokens
    feed(prim, 1)
    assert prim.predictions() == []
    # equal epochs: the smaller daemon id keeps the robot
    zed = Harness(make_config(tmp_path / "z", id="zed"))
    zed.transport.token(keys.active_token("abe", "aibo", 0), alive=True)
    zed.settle()
    assert zed.status().info["role"] == "standby"
    abe = Harness(make_config(tmp_path / "a", id="abe"))
    abe.transport.token(keys.active_token("zed", "aibo", 0), alive=True)
    abe.settle()
    assert abe.status().info["role"] == "primary"


def test_roger_status_names_the_role(tmp_path: Path) -> None:
    from roger_daemon.tools.status import describe

    prim, standby = pair_of(tmp_path)
    for t in range(3):
        feed(prim, t)
    relay(prim, standby, skip=frozenset({1}))
    assert "daemon spare (standby of prim, 1 pairs missing)" in describe(
        standby.status().to_map())
    assert "daemon prim (primary)" in describe(prim.status().to_map())
    standby.transport.token(TOKEN, alive=False)
    standby.settle()
    assert "daemon spare (primary, took over 1 times)" in describe(standby.status().to_map())


def test_a_standby_started_late_catches_up_from_the_primarys_files(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The primary's newest checkpoint (pairs 0-19) and its log after it (20-24), over the
    sync query; then live records as usual, and the takeover finds every pair."""
    caplog.set_level("INFO", logger="roger_daemon.daemon.standby")
    cfg = make_config(tmp_path / "p", {"every_updates": 10}, id="prim")
    prim = Harness(cfg, wal=new_wal(cfg))
    for t in range(25):
        feed(prim, t)
    prim.transport.published.clear()
    standby = _started(make_config(tmp_path / "s", id="spare", role="standby"),
                       others=[TOKEN], peers=(prim,), wal=True)
    standby.settle()
    assert "caught up with prim: 20 updates from its checkpoint, 5 records after it" in \
        caplog.text
    assert standby.rt.updates == 25 and digest(standby) == digest(prim)
    st = standby.status()
    assert st.info["standby_syncs"] == 1 and st.info["standby_in_sync"]
    for t in range(25, 35):
        feed(prim, t)
        feed(standby, t)
        relay(prim, standby)
    assert digest(standby) == digest(prim) == reference_digest(prim, 35)
    standby.transport.token(TOKEN, alive=False)
    standby.settle()
    assert standby.predictions()[-1].updates == 35


def test_a_primary_that_yields_catches_up_with_the_daemon_that_serves(tmp_path: Path) -> None:
    """The returning primary: it had pairs 0-9, the standby that took over learned 10-19."""
    pcfg = make_config(tmp_path / "p", id="prim")
    prim = Harness(pcfg, wal=new_wal(pcfg))
    spare = _started(make_config(tmp_path / "s", {"every_updates": 15}, id="spare",
                                 role="standby"), others=[TOKEN], wal=True)
    for t in range(10):
        feed(prim, t)
        feed(spare, t)
    relay(prim, spare)
    spare.transport.token(TOKEN, alive=False)
    for t in range(10, 20):
        feed(spare, t)
    assert spare.rt.updates == 20 and prim.rt.updates == 10
    prim.transport.peers.append(spare.transport)
    prim.transport.token(keys.active_token("spare", "aibo", 1), alive=True)
    prim.settle()
    assert prim.status().info["role"] == "standby"
    assert prim.rt.updates == 20 and digest(prim) == digest(spare) == reference_digest(prim, 20)


def test_in_realtime_the_takeover_answers_on_the_next_tick(tmp_path: Path) -> None:
    standby = _started(make_config(tmp_path / "s", id="spare", role="standby",
                                   clock="realtime"), others=[TOKEN])
    feed(standby, 0)
    standby.clock.advance(0.1)
    standby.settle()
    assert standby.predictions() == []  # another daemon serves it
    standby.transport.token(TOKEN, alive=False)
    standby.settle()
    standby.clock.advance(0.1)
    standby.service.step(0)
    # every answer (the first tick's too) counts the held pair the takeover queued
    answers = {(p.tick, p.updates) for p in standby.predictions()}
    assert answers == {(0, 1)}

"""Offline replay and log-tail catch-up on sessions recorded by the daemon's own code
(``tests/daemon_sessions.py``), read from their decision records (format version 2) and, as
an older daemon would have written them, by re-pairing their inputs (version 1)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import msgpack
import numpy as np
import pytest
from daemon_sessions import START_NS, as_version_1, daemon_checkpoint, record_session
from mcap_testing import copy_log

from protocols import Action, Perception
from roger_daemon.cli import main as roger
from roger_daemon.daemon.pairing import Pairing
from roger_daemon.labels import majority_labels
from roger_daemon.learner import load_model
from roger_daemon.recording import (
    CatchUpError,
    is_complete,
    log_tail,
    read_timeline,
)
from roger_daemon.replay import replay_session
from roger_daemon.replay.compare import REL_TOL

TOL = REL_TOL


def _rewrite(src: Path, dst: Path, edit: Callable[[str, int, bytes], bytes]) -> None:
    """Copy a log, passing each payload through ``edit(topic, index_in_topic, data)``."""
    copy_log(src, dst, edit=edit)


@pytest.fixture(scope="module")
def busy(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """A session with mode changes, out-of-order halves, a lost action and a bad payload."""
    return record_session(
        tmp_path_factory.mktemp("busy"), n_ticks=150,
        modes={40: "predict", 60: "learn+predict", 90: "learn", 100: "learn+predict",
               120: "pause", 125: "learn+predict"},
        action_first=(5, 6, 70), drop_action=(10, 111), garbage=(12,), checkpoint_at=(50,),
    )


def test_replay_reproduces_the_recorded_model(busy, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    res = replay_session(busy.paths)
    assert res.ok(TOL), res.summary(TOL)
    assert len(res.diffs) == len(busy.predictions) > 100
    assert res.max_mean_diff() <= TOL and res.max_var_diff() <= TOL
    assert res.max_multimap_diff() <= TOL
    assert all(d.expert_match and d.sizes_match and d.labels_match is not False
               for d in res.diffs)
    assert [p.tick for p in res.pairs] == [t for t, *_ in busy.pairs]
    assert res.labels == [lab for *_, lab in busy.pairs]
    assert res.n_experts == busy.model.n_experts >= 2
    assert res.n_learned == busy.model.n_learned
    np.testing.assert_array_equal(res.assignments, busy.model.assignments())
    tl = res.timeline
    assert tl.decisions and tl.invalid["not_msgpack"] == 1
    assert res.seed == 7 and res.model_kind == "roger"
    # the start model's and the checkpoint's digests the daemon recorded are reproduced
    assert [c.updates for c in res.digests] == [0, 50] and all(c.match for c in res.digests)
    assert res.bit_identical() and res.summary(TOL)["model_digests"] == {"checked": 2,
                                                                         "matched": 2}
    # read as a daemon without decision records wrote it, the inputs give the same pairs
    old = replay_session(as_version_1(busy.paths[0], tmp_path / "v1.mcap"))
    assert old.ok(TOL) and not old.timeline.decisions and len(old.diffs) == len(res.diffs)
    assert [p.tick for p in old.pairs] == [p.tick for p in res.pairs]
    tl = old.timeline
    assert tl.invalid["not_msgpack"] == 1
    assert tl.ignored_not_learning == 2 * (20 + 5)  # mode predict at 40-59, pause at 120-124
    assert tl.unpaired == (2, 0)  # ticks 10 and 111 never got their action


def test_replay_cli_check_passes_and_fails_on_a_perturbed_prediction(
    busy, tmp_path: Path, capsys: pytest.CaptureFixture[str]  # type: ignore[no-untyped-def]
) -> None:
    path = busy.paths[0]
    assert roger(["replay", str(path), "--check", "--no-progress"]) == 0
    assert "result:       OK, bit-identical" in capsys.readouterr().out

    def bump(topic: str, i: int, data: bytes) -> bytes:
        if topic.endswith("/prediction") and i == 77:
            m = msgpack.unpackb(data, raw=False)
            m["mean"][0] = m["mean"][0] * (1 + 1e-4) + 1e-6  # far beyond REL_TOL
            out: bytes = msgpack.packb(m, use_bin_type=True)
            return out
        return data

    bad = tmp_path / "perturbed.mcap"
    _rewrite(path, bad, bump)
    assert roger(["replay", str(bad), "--check", "--json"]) == 1
    rep = json.loads(capsys.readouterr().out)
    assert rep["mismatches"] == 1 and not rep["ok"]
    assert rep["max_rel_err"] > 1e-5 and rep["verdict"] == "MISMATCH"
    assert rep["first_mismatch"]["tick"] == busy.predictions[77].tick
    assert rep["first_divergence"]["tick"] == busy.predictions[77].tick
    assert rep["first_divergence"]["kind"] == "float"
    assert roger(["replay", str(bad), "--no-progress"]) == 0  # report only
    assert roger(["replay", str(bad), "--check", "--tolerance", "1e-3", "--no-progress"]) == 0
    assert "OK, within tolerance" in capsys.readouterr().out


def test_replay_with_other_params_from_a_config_mismatches(
    busy, tmp_path: Path, capsys: pytest.CaptureFixture[str]  # type: ignore[no-untyped-def]
) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text("[daemon]\nseed = 7\n[learner]\ntheta_n = 0.3\n"
                   "[[robots]]\nid = \"sim\"\nx_dim = 1\ny_dim = 1\n")
    assert roger(["replay", str(busy.paths[0]), "--config", str(cfg), "--check", "--json"]) == 1
    rep = json.loads(capsys.readouterr().out)
    assert rep["params"]["theta_n"] == 0.3 and rep["seed"] == 7
    # the session was recorded with the paper's parameters (the "paper" preset)
    paper = '[learner]\npreset = "paper"\nnu0 = 24.0\n'  # the session's (default: x_dim + 1)
    cfg.write_text(f"[daemon]\nseed = 7\n{paper}[[robots]]\nid = \"sim\"\nx_dim = 1\ny_dim = 1\n")
    assert roger(["replay", str(busy.paths[0]), "--config", str(cfg), "--check"]) == 0
    cfg.write_text(f"[daemon]\nseed = 8\n{paper}[[robots]]\nid = \"sim\"\nx_dim = 1\ny_dim = 1\n")
    assert roger(["replay", str(busy.paths[0]), "--config", str(cfg), "--check"]) == 1
    cfg.write_text("[daemon]\nrate_hz = \"fast\"\n")
    assert roger(["replay", str(busy.paths[0]), "--config", str(cfg)]) == 2


def test_the_recorded_model_digests_catch_another_model(busy) -> None:  # type: ignore[no-untyped-def]
    """Another seed: the start model is not the session's, nor is the checkpoint's model."""
    res = replay_session(busy.paths, seed=8)
    assert [c.match for c in res.digests] == [False, False] and not res.bit_identical()
    assert any("recorded checkpoint digests" in w for w in res.warnings)


@pytest.mark.integration
def test_a_daemon_with_learner_workers_records_the_same_decisions(tmp_path: Path) -> None:
    """The model in a learner worker process (``[daemon] workers = "process"``): the decision
    records come from the same runtime bookkeeping, so the log replays exactly, digests too,
    and says what the inline daemon's says."""
    kw = {"n_ticks": 60, "resets": (30,), "checkpoint_at": (10,)}
    inline = record_session(tmp_path / "inline", **kw)  # type: ignore[arg-type]
    workers = record_session(tmp_path / "workers", workers=True, **kw)  # type: ignore[arg-type]
    res = replay_session(workers.paths)
    assert res.bit_identical() and len(res.diffs) == 60
    assert [c.match for c in res.digests] == [True, True]
    ref = read_timeline(inline.paths)
    assert [[p.tick for p in seg.pairs] for seg in res.timeline.segments] == [
        [p.tick for p in seg.pairs] for seg in ref.segments]
    assert [(p.tick, p.updates, p.expert) for p in workers.predictions] == [
        (p.tick, p.updates, p.expert) for p in inline.predictions]


def test_replay_across_reset_and_rotated_parts(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    s = record_session(tmp_path, n_ticks=120, resets=(70,),
                       recorder_options={"rotate_bytes": 3000})
    assert len(s.paths) >= 3
    res = replay_session(s.paths)
    assert res.ok(TOL) and len(res.timeline.segments) == 2
    assert res.n_learned == s.model.n_learned == 50
    np.testing.assert_array_equal(res.assignments, s.model.assignments())
    # the CLI finds the other parts from the first one
    assert roger(["replay", str(s.paths[0]), "--check", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["files"]) == len(s.paths)


def test_replay_aibo_sized_stream(tmp_path: Path) -> None:
    s = record_session(tmp_path, n_ticks=40, stream="subtask", robot="aibo")
    res = replay_session(s.paths[0])
    assert res.ok(TOL) and res.timeline.dims is not None and res.timeline.dims.x == 23


def test_replay_of_a_footerless_log_reproduces_what_it_kept(tmp_path: Path) -> None:
    s = record_session(tmp_path / "a", n_ticks=100, close=False)
    cut = tmp_path / "killed.mcap"
    shutil.copyfile(s.paths[0], cut)  # what a SIGKILL leaves: the flushed chunks
    assert s.recorder is not None
    s.recorder.close()
    assert not is_complete(cut)
    res = replay_session(cut)
    assert res.ok(TOL) and res.timeline.incomplete_files == [str(cut)]
    assert 60 <= len(res.pairs) < 100 and len(res.diffs) == len(res.pairs)


# -- catch-up --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def crash(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """Session A is killed at tick 130 (checkpoint at 60 updates); session B is the daemon's
    next life: it resumes from the checkpoint plus A's log tail (start-up recovery)."""
    root = tmp_path_factory.mktemp("crash")
    logs = root / "logs"
    logs.mkdir()
    a = record_session(root / "a", n_ticks=130, close=False, checkpoint_at=(60,),
                       drop_action=(20,))
    shutil.copyfile(a.paths[0], logs / a.paths[0].name)  # the file as the kill left it
    assert a.recorder is not None
    a.recorder.close()
    tail = log_tail(logs, learned=60, robot="sim", last_tick=60)
    model = load_model(a.checkpoints[60])
    for p in tail.pairs:
        model.learn_one(p.x, p.y)
    b = record_session(logs, n_ticks=60, tick0=130, checkpoint_dir=a.checkpoint_dir,
                       recover=True)
    assert b.rt.recovered_pairs == len(tail.pairs)
    return {"a": a, "logs": logs, "tail": tail, "caught_up": model, "b": b,
            "b_start": load_model(b.start_state)}


def test_log_tail_gives_the_pairs_after_the_checkpoint(crash) -> None:  # type: ignore[no-untyped-def]
    tail = crash["tail"]
    a = crash["a"]
    assert tail.pairs[0].index == 60 and tail.pairs[0].tick == 61  # tick 20 had no action
    assert tail.incomplete_files and 100 <= tail.final_updates < 129
    kept = [t for t, *_ in a.pairs][60:tail.final_updates]
    assert [p.tick for p in tail.pairs] == kept


def test_checkpoint_plus_tail_equals_the_uninterrupted_model(crash) -> None:  # type: ignore[no-untyped-def]
    """The resumed model equals a model that learned the same logged pairs without a crash."""
    from roger_daemon.learner import Roger, RogerParams

    a, model = crash["a"], crash["caught_up"]
    ref = Roger(d_x=1, d_y=1, params=RogerParams(nu0=24.0), seed=7)  # the session's nu0
    for _, x, y, _ in a.pairs[: model.n_learned]:
        ref.learn_one(x, y)
    def same(m1: object, m2: object) -> None:
        np.testing.assert_array_equal(m1.assignments(), m2.assignments())  # type: ignore[attr-defined]
        assert m1.expert_sizes() == m2.expert_sizes()  # type: ignore[attr-defined]
        for q in np.linspace(0.0, 1.0, 7):
            p, r = m1.predict_one([q]), m2.predict_one([q])  # type: ignore[attr-defined]
            np.testing.assert_array_equal(p.mean, r.mean)
            np.testing.assert_array_equal(p.var, r.var)
            mm1 = m1.predict_multimap([q])  # type: ignore[attr-defined]
            mm2 = m2.predict_multimap([q])  # type: ignore[attr-defined]
            assert [(e.expert_id, e.gate_prob, e.n_points) for e in mm1] == [
                (e.expert_id, e.gate_prob, e.n_points) for e in mm2]

    same(model, ref)
    # and they go on identically (state_dict slot layout may differ; behaviour must not)
    cont = load_model(model.state_dict())
    for _, x, y, _ in crash["b"].pairs[:30]:
        cont.learn_one(x, y)
        ref.learn_one(x, y)
    same(cont, ref)


def test_log_tail_across_sessions(crash) -> None:  # type: ignore[no-untyped-def]
    tail, b = crash["tail"], crash["b"]
    both = log_tail(crash["logs"], learned=60, robot="sim")
    assert [p.tick for p in both.pairs] == [p.tick for p in tail.pairs] + [t for t, *_ in b.pairs]
    assert len(both.sessions) == 2 and both.final_updates == b.model.n_learned
    later = log_tail(crash["logs"], learned=tail.final_updates + 5, robot="sim")
    assert later.pairs[0].tick == b.pairs[5][0]
    assert later.sessions == both.sessions[1:]


def test_log_tail_refuses_what_it_cannot_continue(crash) -> None:  # type: ignore[no-untyped-def]
    logs = crash["logs"]
    with pytest.raises(CatchUpError, match="end at"):
        log_tail(logs, learned=10_000, robot="sim")
    with pytest.raises(CatchUpError, match="tick"):
        log_tail(logs, learned=60, robot="sim", last_tick=59)
    only_b = crash["b"].paths
    with pytest.raises(CatchUpError, match="start at"):
        log_tail(only_b, learned=60, robot="sim")


def test_replay_of_a_resumed_session_needs_its_checkpoint(crash) -> None:  # type: ignore[no-untyped-def]
    b = crash["b"]
    res = replay_session(b.paths)
    assert not res.ok(TOL) and res.unreplayable == len(b.predictions)
    assert any("checkpoint" in w for w in res.warnings)
    res = replay_session(b.paths, initial_model=crash["b_start"])
    assert res.ok(TOL) and len(res.diffs) == len(b.predictions)


# -- pieces ----------------------------------------------------------------------------------


def test_pairing() -> None:
    tr = Pairing(window=3)
    p = [Perception("r", t, 0.0, x=[float(t)]) for t in range(6)]
    a = [Action("r", t, 0.0, y=[float(-t)]) for t in range(6)]
    assert tr.perception(p[0]) is None
    pair = tr.action(a[0])
    assert pair is not None and pair[0] is p[0] and pair[1] is a[0]
    assert tr.action(a[1]) is None
    newer = Perception("r", 1, 0.5, x=[9.0])
    assert tr.perception(newer) == (newer, a[1])
    assert tr.perception(p[2]) is None
    assert tr.perception(Perception("r", 2, 0.7, x=[7.0])) is None  # newest of tick 2 wins
    got = tr.action(a[2])
    assert got is not None and float(got[0].x[0]) == 7.0
    assert tr.action(a[2]) is None  # a tick pairs once
    for t in range(3, 6):
        tr.perception(p[t])
    assert tr.evicted_perceptions == 0 and tr.pending == (3, 1)
    tr.perception(Perception("r", 9, 0.0, x=[0.0]))
    assert tr.evicted_perceptions == 1


def test_majority_labels_ties_go_to_the_first_by_name() -> None:
    """One rule everywhere (roger_daemon.labels): a tie does not depend on arrival order."""
    assert majority_labels([0, 0, 1, 1, 1, 0], ["b", "a", "x", "y", "y", "a"]) == {0: "a", 1: "y"}
    assert majority_labels([2, 2], ["q", "p"]) == majority_labels([2, 2], ["p", "q"]) == {2: "p"}
    assert majority_labels([1, 1, 1, 2], ["", "", "b", ""]) == {1: "b", 2: ""}
    assert majority_labels([], []) == {}


def test_read_timeline_segments(busy) -> None:  # type: ignore[no-untyped-def]
    tl = read_timeline(busy.paths)
    assert tl.robot == "sim" and tl.resets == 0
    seg = tl.segments[0]
    assert [p.index for p in seg.pairs] == list(range(len(seg.pairs)))
    assert all(p.updates <= seg.end_updates for p in seg.predictions)


def _handmade(tmp_path: Path, events: list[tuple[str, object]], **meta: object) -> Path:
    """A log from (kind, message) events, one per 10 ms, metadata from session_metadata."""
    from protocols import encode, keys
    from roger_daemon.recording import SessionRecorder, session_metadata

    md = session_metadata(robot="r", dims=(1, 1), seed=1, **meta)  # type: ignore[arg-type]
    with SessionRecorder(tmp_path, robot="r", metadata=md, start_ns=START_NS) as rec:
        for i, (kind, msg) in enumerate(events):
            rec.write(keys.key("r", kind), encode(msg), log_time_ns=START_NS + i * 10**7,  # type: ignore[arg-type]
                      publish_time_ns=START_NS, sequence=0)
    return rec.path


def test_timeline_pairs_only_while_learning_like_the_daemon(tmp_path: Path) -> None:
    from protocols import Control

    def p(t: int) -> tuple[str, object]:
        return "perception", Perception("r", t, 0.0, x=[float(t)])

    def a(t: int) -> tuple[str, object]:
        return "action", Action("r", t, 0.0, y=[float(t)], label="s")

    def mode(m: str) -> tuple[str, object]:
        return "control", Control("r", 0, 0.0, op="mode", mode=m)

    events = [p(0), a(0),                      # learned
              mode("predict"), p(1),           # perception not buffered while predicting
              mode("learn"), a(1),             # so action 1 waits in vain
              a(2), mode("pause"), p(2),       # perception 2 ignored: no pair
              mode("learn+predict"), p(3), a(3),
              ("control", Control("r", 0, 0.0, op="reset")), a(4), p(4)]
    tl = read_timeline([_handmade(tmp_path, events)])
    assert [[q.tick for q in s.pairs] for s in tl.segments] == [[0, 3], [4]]
    assert tl.ignored_not_learning == 2 and tl.unpaired == (0, 0)


def test_timeline_uses_the_sessions_pair_window(tmp_path: Path) -> None:
    events: list[tuple[str, object]] = [("action", Action("r", 0, 0.0, y=[0.0]))]
    events += [("perception", Perception("r", t, 0.0, x=[0.0])) for t in range(100, 170)]
    events += [("perception", Perception("r", 0, 0.0, x=[0.0]))]
    narrow = read_timeline([_handmade(tmp_path / "a", events, pair_window=64)])
    assert narrow.pair_window == 64 and len(narrow.pairs) == 1  # actions wait; perceptions evict
    events = [("perception", Perception("r", 0, 0.0, x=[0.0]))]
    events += [("perception", Perception("r", t, 0.0, x=[0.0])) for t in range(100, 170)]
    events += [("action", Action("r", 0, 0.0, y=[0.0]))]
    assert read_timeline([_handmade(tmp_path / "b", events, pair_window=64)]).pairs == []
    assert len(read_timeline([_handmade(tmp_path / "c", events, pair_window=128)]).pairs) == 1
    cfg = "[daemon]\npair_window = 100\n"
    assert read_timeline([_handmade(tmp_path / "d", events, config_text=cfg)]).pair_window == 100


def test_replay_warns_when_the_daemon_dropped_pairs(tmp_path: Path) -> None:
    from protocols import Status

    def st(dropped: int) -> tuple[str, object]:
        return "status", Status("r", 0, 0.0, daemon="d", mode="learn", ticks=0, updates=0,
                                updates_per_s=0.0, experts=0, queue_depth=0, dropped=dropped)

    events = [st(3), ("perception", Perception("r", 1, 0.0, x=[0.5])),
              ("action", Action("r", 1, 0.0, y=[0.5])), st(5)]
    res = replay_session(_handmade(tmp_path, events))
    assert res.timeline.daemon_dropped == 2 and any("dropped 2" in w for w in res.warnings)


def test_log_tail_after_a_restored_queue_and_from_session(crash) -> None:  # type: ignore[no-untyped-def]
    tail = crash["tail"]
    ticks = [p.tick for p in tail.pairs]
    assert tail.after_queue(ticks[:5]) == tail.pairs[5:]
    assert tail.after_queue([*ticks, 10_000]) == []  # the log ends inside the queue
    with pytest.raises(CatchUpError, match="queued"):
        tail.after_queue([ticks[1], ticks[0]])
    sessions = log_tail(crash["logs"], learned=60, robot="sim").sessions
    again = log_tail(crash["logs"], learned=60, robot="sim", from_session=sessions[0])
    assert [p.tick for p in again.pairs][: len(ticks)] == ticks
    with pytest.raises(CatchUpError, match="not among"):
        log_tail(crash["logs"], learned=60, robot="sim", from_session="roger-sim-nope")


def test_replay_of_a_session_resumed_from_a_daemon_checkpoint_with_a_queue(
    crash, tmp_path: Path  # type: ignore[no-untyped-def]
) -> None:
    """A daemon checkpoint (model at 60 updates + 8 queued pairs) and the session that resumed
    from it: ``roger replay --checkpoint`` reproduces everything. The session's own log names
    the queued pairs it learned first (decision records); read as version 1, the queue must
    come from the checkpoint."""
    a = crash["a"]
    queued = a.pairs[60:68]
    ck_path = daemon_checkpoint(tmp_path / "ck", "sim", a.checkpoints[60], dims=a.dims,
                                labels=[p[3] for p in a.pairs[:60]], queue=queued)
    b = record_session(tmp_path / "b", n_ticks=40, tick0=300, checkpoint_dir=tmp_path / "ck")
    assert b.rt.updates == 60 + 8 + 40 and [t for t, *_ in b.pairs][:8] == [q[0] for q in queued]
    plain = tmp_path / "model.npz"
    np.savez(plain, **a.checkpoints[60])  # the model alone: the queue is missing
    assert roger(["replay", str(b.paths[0]), "--checkpoint", str(ck_path), "--check",
                  "--no-progress"]) == 0
    assert roger(["replay", str(b.paths[0]), "--checkpoint", str(plain), "--check",
                  "--no-progress"]) == 0  # the log names the queued pairs
    old = as_version_1(b.paths[0], tmp_path / "b-v1.mcap")
    assert roger(["replay", str(old), "--checkpoint", str(ck_path), "--check",
                  "--no-progress"]) == 0
    assert roger(["replay", str(old), "--checkpoint", str(plain), "--check",
                  "--no-progress"]) == 1
    assert roger(["replay", str(b.paths[0]), "--check", "--no-progress"]) == 1


def test_replay_names_a_checkpoint_whose_daemon_arrays_do_not_fit_together(
    crash, tmp_path: Path, capsys: pytest.CaptureFixture[str]  # type: ignore[no-untyped-def]
) -> None:
    """A checkpoint whose newest-pair arrays disagree stops ``roger replay --checkpoint`` with
    exit 2 and a message naming the file and the fault (no traceback)."""
    from roger_daemon.daemon.checkpoint import read_checkpoint, write_checkpoint

    a = crash["a"]
    good = read_checkpoint(daemon_checkpoint(tmp_path / "ck", "sim", a.checkpoints[60],
                                             dims=a.dims, labels=[p[3] for p in a.pairs[:60]],
                                             last_tick=a.pairs[59][0]))
    daemon = dict(good.daemon)
    daemon["newest_pair_tick"] = np.array([59], dtype=np.int64)  # a tick without its pair
    daemon["newest_pair_x"] = np.zeros((0, a.dims.x))
    daemon["newest_pair_y"] = np.zeros((0, a.dims.y))
    bad, _ = write_checkpoint(tmp_path / "bad", "sim", dict(good.model), daemon, good.meta)
    capsys.readouterr()
    assert roger(["replay", str(crash["b"].paths[0]), "--checkpoint", str(bad),
                  "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"checkpoint {bad}: daemon state's newest pair has 1 ticks" in err
    assert "Traceback" not in err


def test_replay_refuses_files_of_different_sessions(crash) -> None:  # type: ignore[no-untyped-def]
    files = sorted(crash["logs"].glob("*.mcap"))
    assert len(files) == 2
    with pytest.raises(ValueError, match="2 sessions"):
        replay_session(files)


def test_merge_groups_saves_the_experts_merged_per_group(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``roger replay --merge-groups --save-checkpoint DIR`` saves what
    :func:`roger_daemon.groups.merge_groups` builds from the replayed model and the logged
    pairs (the experiment's merged groups), labelled by group; it refuses without DIR."""
    from roger_daemon.daemon.checkpoint import array_digest, list_checkpoints, read_checkpoint
    from roger_daemon.daemon.robot_state import RobotState
    from roger_daemon.groups import merge_groups

    s = record_session(tmp_path / "logs", n_ticks=150)  # 3 experts, named seek and trap
    assert roger(["replay", str(s.paths[0]), "--merge-groups", "--no-progress"]) == 2
    out = tmp_path / "merged"
    capsys.readouterr()
    assert roger(["replay", str(s.paths[0]), "--merge-groups", "--save-checkpoint", str(out),
                  "--no-progress", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    res = replay_session(s.paths)
    assert res.model is not None
    x = np.array([p.x for p in res.pairs])
    y = np.array([p.y for p in res.pairs])
    want, groups = merge_groups(x, y, res.labels, res.model, params=res.model.params,
                                seed=res.seed)
    ck = read_checkpoint(list_checkpoints(out, res.robot)[0])
    assert ck.meta.model_digest == array_digest(want.state_dict())
    assert RobotState.from_arrays(ck.daemon).labels() == groups
    assert ck.meta.learner.params == want.params.to_mapping()  # one particle: the merged model's
    assert want.n_experts == len(set(groups)) == 2 < res.model.n_experts == 3
    assert sorted(report["merged_groups"].values()) == sorted(set(groups))


def test_split_gates_saves_the_split_model_with_the_pairs_labels(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``roger replay --split-gates --save-checkpoint DIR`` saves the replayed model's split
    gates as a one-particle ROGER model (:func:`roger_daemon.gate_split_model.split_model`),
    the logged labels unchanged, and the checkpoint loads into a model answering as the split
    gates do; without DIR, or with ``--merge-groups`` too, it exits 2."""
    from roger_daemon.config.models import load_model
    from roger_daemon.daemon.checkpoint import array_digest, list_checkpoints, read_checkpoint
    from roger_daemon.daemon.robot_state import RobotState
    from roger_daemon.gate_split import SplitGates
    from roger_daemon.gate_split_model import split_model

    s = record_session(tmp_path / "logs", n_ticks=150)
    out = tmp_path / "split"
    capsys.readouterr()
    assert roger(["replay", str(s.paths[0]), "--split-gates", "--no-progress"]) == 2
    assert "--split-gates needs --save-checkpoint DIR" in capsys.readouterr().err
    assert roger(["replay", str(s.paths[0]), "--split-gates", "--merge-groups",
                  "--save-checkpoint", str(out), "--no-progress"]) == 2
    assert "choose one" in capsys.readouterr().err and not out.exists()
    assert roger(["replay", str(s.paths[0]), "--split-gates", "--save-checkpoint", str(out),
                  "--no-progress", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    res = replay_session(s.paths)
    assert res.model is not None
    x = np.array([p.x for p in res.pairs])
    gates = SplitGates(res.model, x, seed=int(res.seed or 0))
    want = split_model(gates)
    ck = read_checkpoint(list_checkpoints(out, res.robot)[0])
    assert ck.meta.model_digest == array_digest(want.state_dict())
    assert RobotState.from_arrays(ck.daemon).labels() == res.labels
    assert ck.meta.learner.params == want.params.to_mapping()
    assert len(report["split_gates"]) == len(gates.parts) == want.n_experts
    served = load_model(ck.model)
    for probe in x[::25]:
        assert served.predict_table(probe)[1].means.tolist() == \
            gates.predict_table(probe)[1].means.tolist()

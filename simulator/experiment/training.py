"""Phases 2-4 of the experiment: demonstration data from MCAP, downsampling, training, and the
check that the daemon (and a replay of its log) learns exactly the same model.

* :func:`load_demonstrations` reads the recorded sessions (``roger record`` files) with the
  daemon's own pairing rules (:func:`roger_daemon.recording.read_timeline`).
* :func:`train` learns the downsampled stream incrementally, one ``learn_one`` per pair, in
  order, with the learner alone (no I/O).
* :func:`daemon_check` feeds the same stream to a real ``roger daemon`` over Zenoh in lockstep
  (action(t), then perception(t), then wait for prediction(t)), stops it (final checkpoint),
  replays the daemon's own MCAP recording offline, and compares the three models: state
  digests, assignments, expert counts, majority labels and predictions.
* :func:`write_model_checkpoint` writes a trained model as a daemon checkpoint (with the
  subtask labels of the learned pairs), which ``roger daemon`` resumes from.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from protocols.messages import Dims
from roger_daemon.atomic import write_json
from roger_daemon.daemon.checkpoint import array_digest, write_checkpoint
from roger_daemon.daemon.checkpoint_meta import CheckpointMeta, LearnerSpec
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.replay.compare import REL_TOL

__all__ = [
    "Demonstrations",
    "daemon_check",
    "label_state",
    "learner_table",
    "load_demonstrations",
    "model_fingerprint",
    "train",
    "write_model_checkpoint",
]

FloatArray = npt.NDArray[np.float64]


@dataclass
class Demonstrations:
    """All demonstration pairs in learning order (location order, then tick order)."""

    x: FloatArray  # (n, 23)
    y: FloatArray  # (n, 9)
    labels: list[str]
    location: npt.NDArray[np.int64]  # start location of the episode of each pair
    tick: npt.NDArray[np.int64]
    unpaired: int  # perceptions/actions left without a partner in the logs
    #: the commands the robot executed, where they differ from ``y`` (perturbed
    #: demonstrations, simulator/controllers/demo_noise.py); None: ``y`` was executed
    executed: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, idx: npt.NDArray[np.int64]) -> Demonstrations:
        """The demonstrations at indices ``idx``, in that order."""
        return Demonstrations(self.x[idx], self.y[idx], [self.labels[i] for i in idx],
                              self.location[idx], self.tick[idx], self.unpaired,
                              None if self.executed is None else self.executed[idx])


def load_demonstrations(sessions: Sequence[tuple[int, Sequence[Path]]]) -> Demonstrations:
    """Pairs of each ``(location, mcap files)`` session, concatenated in the given order."""
    from roger_daemon.recording import read_timeline

    xs: list[FloatArray] = []
    ys: list[FloatArray] = []
    labels: list[str] = []
    locs: list[int] = []
    ticks: list[int] = []
    unpaired = 0
    for loc, files in sessions:
        tl = read_timeline(files, robot="aibo")
        unpaired += sum(tl.unpaired)
        for p in tl.pairs:
            xs.append(np.asarray(p.x, dtype=np.float64))
            ys.append(np.asarray(p.y, dtype=np.float64))
            labels.append(p.label)
            locs.append(loc)
            ticks.append(p.tick)
    if not xs:
        raise ValueError("the demonstration logs hold no training pairs")
    return Demonstrations(np.array(xs), np.array(ys), labels, np.array(locs, dtype=np.int64),
                          np.array(ticks, dtype=np.int64), unpaired)


def learner_table(params: Any) -> dict[str, Any]:
    """A ``[learner]`` TOML table for ``params`` (``None`` values left out)."""
    return {k: v for k, v in params.to_mapping().items() if v is not None}


def train(model: Any, x: FloatArray, y: FloatArray,
          progress: Callable[[int], None] | None = None, every: int = 50) -> float:
    """Learn the pairs in order; return the wall time in seconds."""
    t0 = time.perf_counter()
    for i in range(len(x)):
        model.learn_one(x[i], y[i])
        if progress is not None and (i + 1) % every == 0:
            progress(every)
    if progress is not None and len(x) % every:
        progress(len(x) % every)
    return time.perf_counter() - t0


def model_fingerprint(model: Any) -> str:
    """SHA-256 of the model's ``state_dict`` arrays (names, dtypes, shapes, bytes)."""
    return array_digest(model.state_dict())


def label_state(labels: Sequence[str]) -> RobotState:
    """The daemon's label state for pairs learned with ``labels`` (empty queue).

    The vocabulary is sorted, so that the daemon's tie rule (lowest code) is the alphabetical
    one of :func:`roger_daemon.labels.majority_labels`.
    """
    return RobotState.from_labels(labels, vocab=sorted(set(labels)))


def write_model_checkpoint(directory: Path, model: Any, labels: Sequence[str], *,
                           model_kind: str, seed: int, params: Any,
                           robot: str = "aibo") -> tuple[Path, CheckpointMeta]:
    """Write ``model`` as the daemon's checkpoint of ``robot`` in ``directory``.

    Returns its path and metadata (``model_digest`` identifies the model).
    """
    if len(labels) != int(model.n_learned):
        raise ValueError(f"{len(labels)} labels for {model.n_learned} learned pairs")
    d_x, d_y = int(model.d_x), int(model.d_y)
    daemon = label_state(labels).to_arrays(Dims(d_x, d_y))
    meta = CheckpointMeta(
        reason="experiment", updates=int(model.n_learned), x_dim=d_x, y_dim=d_y,
        created_unix_ns=time.time_ns(), daemon="experiment",
        learner=LearnerSpec(model_kind, seed, params.to_mapping()))
    return write_checkpoint(directory, robot, model.state_dict(), daemon, meta, keep=1)


def _probe_predictions(model: Any, x: FloatArray
                       ) -> tuple[FloatArray, list[list[int]], list[FloatArray]]:
    """Chosen means, multimap expert ids (structure) and multimap floats (gate, mean)."""
    means = []
    ids: list[list[int]] = []
    floats: list[FloatArray] = []
    for q in x:
        means.append(np.asarray(model.predict_one(q).mean))
        mm = model.predict_multimap(q)
        ids.append([int(e.expert_id) for e in mm])
        floats.append(np.array([[float(e.gate_prob), *np.asarray(e.mean).tolist()]
                                for e in mm]))
    return np.array(means), ids, floats


def _probe_agreement(offline: Any, daemon: Any, x: FloatArray) -> dict[str, Any]:
    """Probe predictions of two models: structure exactly, floats within ``REL_TOL``."""
    from roger_daemon.replay.compare import rel_err

    m_off, ids_off, f_off = _probe_predictions(offline, x)
    m_dae, ids_dae, f_dae = _probe_predictions(daemon, x)
    ids_equal = ids_off == ids_dae
    rel = rel_err(m_off, m_dae) if len(x) else 0.0
    if ids_equal:
        rel = max([rel, *(rel_err(a, b) for a, b in zip(f_off, f_dae, strict=True))])
    return {
        "probe_predictions": len(x),
        "probe_max_abs_diff": float(np.max(np.abs(m_off - m_dae))) if len(x) else 0.0,
        "probe_max_rel_err": rel if ids_equal else float("inf"),
        "probe_multimap_experts_equal": ids_equal,
    }


def daemon_check(
    x: FloatArray,
    y: FloatArray,
    labels: Sequence[str],
    offline: Any,
    *,
    params: Any,
    seed: int,
    workdir: Path,
    progress: Callable[[int], None] | None = None,
    probes: int = 200,
) -> dict[str, Any]:
    """Feed the stream to a real daemon in lockstep and compare with ``offline`` (see module).

    ``offline`` must not have predicted anything yet (its state digest is compared as is).
    """
    from roger_daemon.daemon.checkpoint import load_newest
    from roger_daemon.harness import Client, DaemonProcess, write_config
    from roger_daemon.labels import majority_labels, majority_labels_coded
    from roger_daemon.learner import load_model
    from roger_daemon.recording import list_session_files
    from roger_daemon.replay import replay_session
    from simulator.experiment.procs import CHILDREN, child_env, free_port

    if workdir.exists():
        shutil.rmtree(workdir)  # one session, one checkpoint: what this check produced
    workdir.mkdir(parents=True)
    t0 = time.perf_counter()
    offline_digest = model_fingerprint(offline)
    port = free_port()
    cfg = write_config(
        workdir / "daemon.toml",
        port=port,
        workdir=workdir,
        daemon={"mode": "learn+predict", "clock": "lockstep", "seed": seed},
        checkpoint={"on_shutdown": True, "every_updates": 0, "every_s": 0.0},
        recording={"enabled": True},
        learner=learner_table(params),
        # the learner table is fully resolved (scaling included): no robot profile on top
        robots=({"id": "aibo", "model": "roger", "profile": "none"},),
    )
    with CHILDREN.spawning():  # a stop of the experiment reaches it (procs.Children)
        daemon = DaemonProcess(cfg, args=["--fresh"], log=workdir / "daemon.log",
                               env=child_env())
        CHILDREN.add(daemon.proc)
    client = None
    try:
        daemon.wait_ready(120)
        client = Client(f"tcp/127.0.0.1:{port}")
        client.wait_daemon(30)
        for i in range(len(x)):
            client.action(i, y[i], labels[i])
            client.perception(i, x[i])
            client.wait_prediction(i, 60)
            if progress is not None and (i + 1) % 50 == 0:
                progress(50)
            if len(client.predictions) > 512:
                with client._cond:
                    del client.predictions[:256]
        if progress is not None and len(x) % 50:
            progress(len(x) % 50)
        client.close()
        client = None
        code, _ = daemon.terminate(120)
    finally:
        if client is not None:
            client.close()
        daemon.kill()
        CHILDREN.discard(daemon.proc)
    feed_s = time.perf_counter() - t0
    ck = load_newest(workdir / "checkpoints", "aibo")
    if ck is None:
        raise RuntimeError(f"the daemon wrote no checkpoint; see {workdir / 'daemon.log'}")
    from_daemon = load_model(ck.model)
    daemon_digest = array_digest(ck.model)
    files = [sf.path for sf in list_session_files(workdir / "recordings", robot="aibo")]
    replayed = replay_session(files) if files else None
    replay_digest = model_fingerprint(replayed.model) if replayed and replayed.model else ""

    assign = np.asarray(offline.assignments())
    state = RobotState.from_arrays(ck.daemon)
    # the daemon's names (its checkpoint's codes) against the offline model's: one rule
    theirs = majority_labels_coded(np.asarray(from_daemon.assignments()), state.codes,
                                   state.vocab)
    expected = majority_labels(assign, list(labels))
    pick = np.linspace(0, len(x) - 1, min(probes, len(x))).astype(int)
    out: dict[str, Any] = {
        "pairs_fed": len(x),
        "daemon_exit_code": code,
        "daemon_updates": int(from_daemon.n_learned),
        "offline_digest": offline_digest,
        "daemon_digest": daemon_digest,
        "replay_digest": replay_digest,
        "identical_state": offline_digest == daemon_digest,
        "replay_identical_state": replay_digest == offline_digest,
        "assignments_equal": bool(np.array_equal(assign, from_daemon.assignments())),
        "experts_offline": int(offline.n_experts),
        "experts_daemon": int(from_daemon.n_experts),
        "expert_labels_equal": expected == theirs,
        **_probe_agreement(offline, from_daemon, x[pick]),
        "tolerance": REL_TOL,
        "replay": None,
        "checkpoint": str(ck.path),
        "mcap": [str(f) for f in files],
        "wall_s": round(feed_s, 2),
    }
    if replayed is not None:
        summ = replayed.summary(REL_TOL)
        out["replay"] = {k: summ[k] for k in (
            "pairs_learned", "n_experts", "predictions_compared", "predictions_unreplayable",
            "max_abs_diff_mean", "max_rel_err", "verdict", "first_divergence", "mismatches",
            "label_mismatches")}
        out["replay"]["ok"] = bool(replayed.ok(REL_TOL))
    # the structure exactly, the floats within REL_TOL (docs/reproducibility.md); the state
    # digests say whether it was also bit for bit (expected on one machine, one BLAS thread)
    out["bit_identical"] = bool(out["identical_state"] and out["replay_identical_state"])
    out["ok"] = bool(
        out["assignments_equal"]
        and out["experts_offline"] == out["experts_daemon"] and out["expert_labels_equal"]
        and out["probe_max_rel_err"] <= REL_TOL and out["probe_multimap_experts_equal"]
        and out["replay"] is not None and out["replay"]["ok"]
        and out["daemon_updates"] == len(x)
    )
    write_json(workdir / "check.json", out)
    return out


def expert_table(assignments: Sequence[int], labels: Sequence[str],
                 majority: Mapping[int, str]) -> list[dict[str, Any]]:
    """Per expert (largest first): id, points, majority label, share of each subtask."""
    a = np.asarray(assignments)
    lab = np.asarray(labels)
    rows = []
    for e in sorted(set(a.tolist()), key=lambda e: (-int(np.sum(a == e)), e)):
        m = a == e
        rows.append({
            "expert": int(e),
            "points": int(m.sum()),
            "label": majority.get(int(e), ""),
            "by_subtask": {s: int(np.sum(lab[m] == s)) for s in sorted(set(lab.tolist()))},
        })
    return rows

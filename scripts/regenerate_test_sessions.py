"""Regenerate the regression sessions in ``tests/data/sessions/`` and their golden outputs.

Each session is recorded by the project's own processes, over real Zenoh on 127.0.0.1 (free
ports, multicast scouting off): ``roger daemon`` (lockstep clock, recording on, default
learner), ``roger hcc --role demonstrator`` (the hand-coded FSM teaches) and ``roger sim``
(lockstep, fast vision, one episode from one start location). The daemon's session file is
copied to ``tests/data/sessions/<name>.mcap``. Then, from that file alone, by running the code:

* ``<name>.golden.json``: what ``roger replay`` rebuilds (pairs learned, expert count and
  sizes, majority labels, assignments of every pair) and how the replayed model behaves on
  probe inputs taken from the session's perceptions (``predict_one`` and the multimap);
* ``<name>.info.txt``: the exact output of ``roger log info tests/data/sessions/<name>.mcap``.

Usage (from the repository root)::

    .venv/bin/python scripts/regenerate_test_sessions.py            # record + goldens
    .venv/bin/python scripts/regenerate_test_sessions.py --goldens-only
    .venv/bin/python scripts/regenerate_test_sessions.py --only sim-loc8-seed0

Recording aborts (exit 1) if a replay does not reproduce the recorded predictions bit for bit
(recorded and replayed on this machine, one BLAS thread) or a file exceeds 1 MB; the tests then
accept another machine's floats within ``REL_TOL`` (docs/reproducibility.md). A deliberate
learner change makes the recorded predictions stale: record the sessions again (not
``--goldens-only``). Run ``pytest tests/test_regression_sessions.py``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DATA = Path("tests/data/sessions")  # relative to ROOT: the path `log info` prints
MAX_BYTES = 1_000_000
N_PROBES = 12


@dataclass(frozen=True)
class Spec:
    """One regression session: one simulator episode from one start location."""

    name: str
    location: int
    seed: int
    time_limit: float  # seconds of sim time (30 ticks per second)


# Start locations whose demonstration gives the learner several experts in a few hundred
# ticks (in-process, seed 0: location 8 scores after 342 ticks, 3 experts; location 7 ends
# with the ball out after 330 ticks, 3 experts).
SESSIONS = (
    Spec("sim-loc8-seed0", location=8, seed=0, time_limit=15.0),
    Spec("sim-loc7-seed0", location=7, seed=0, time_limit=15.0),
)


def _free_port() -> int:
    from roger_daemon.harness import free_port

    return free_port()


def _daemon_config(path: Path, port: int) -> None:
    path.write_text(
        "# regression session: daemon for roger sim + roger hcc --role demonstrator\n"
        "[daemon]\n"
        'id = "regression"\n'
        'clock = "lockstep"\n'
        "seed = 0\n"
        "\n[zenoh]\n"
        f'listen = ["tcp/127.0.0.1:{port}"]\n'
        "multicast_scouting = false\n"
        "\n[checkpoint]\n"
        'dir = "checkpoints"\n'
        "every_updates = 0\n"
        "every_s = 0.0\n"
        "\n[recording]\n"
        "enabled = true\n"
        'dir = "recordings"\n'
        "\n[[robots]]\n"
        'id = "aibo"\n',
        encoding="utf-8",
    )


def _spawn(args: list[str], cwd: Path, log: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "ROGER_LOG_LEVEL": "INFO", "RUST_LOG": "error",
           "PYTHONPATH": str(ROOT)}
    with open(log, "ab") as f:
        return subprocess.Popen([sys.executable, "-m", "roger_daemon", *args], cwd=cwd,
                                stdout=f, stderr=subprocess.STDOUT, env=env)


def _wait_text(log: Path, text: str, proc: subprocess.Popen[bytes], timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if log.exists() and text in log.read_text(errors="replace"):
            return
        if proc.poll() is not None:
            raise RuntimeError(f"{proc.args!r} exited with {proc.returncode}:\n{log.read_text()}")
        time.sleep(0.05)
    raise TimeoutError(f"{text!r} not in {log} after {timeout} s:\n{log.read_text()}")


def _stop(proc: subprocess.Popen[bytes], timeout: float = 15.0) -> int:
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
        return -9


def _wait_idle(port: int, timeout: float = 60.0) -> dict[str, Any]:
    """Wait until the daemon has handled everything: two statuses in a row with the same tick
    count and an empty training queue (after the simulator and the controller exited)."""
    from protocols.aibo import DIMS
    from roger_daemon.harness import Client

    client = Client(f"tcp/127.0.0.1:{port}", robot="aibo", dims=DIMS, daemon_id="regression")
    try:
        client.wait_daemon()
        end = time.monotonic() + timeout
        last = None
        while time.monotonic() < end:
            st = client.wait_status(timeout=5.0)
            if st.queue_depth == 0 and last is not None and st.ticks == last.ticks:
                return {"ticks": st.ticks, "updates": st.updates, "experts": st.experts,
                        "dropped": st.dropped}
            last = st
        raise TimeoutError("the daemon did not become idle")
    finally:
        client.close()


def record(spec: Spec, out: Path) -> dict[str, Any]:
    """Record one session into ``out`` (an .mcap path); return what the processes reported."""
    work = Path(tempfile.mkdtemp(prefix=f"roger-regression-{spec.name}-"))
    try:
        d_port, s_port = _free_port(), _free_port()
        _daemon_config(work / "daemon.toml", d_port)
        daemon_log, sim_log, hcc_log = work / "daemon.log", work / "sim.log", work / "hcc.log"
        daemon = _spawn(["daemon", "--config", "daemon.toml"], work, daemon_log)
        procs = [daemon]
        try:
            _wait_text(daemon_log, " ready: ", daemon, 60)
            sim_ep, d_ep = f"tcp/127.0.0.1:{s_port}", f"tcp/127.0.0.1:{d_port}"
            hcc = _spawn(["hcc", "--role", "demonstrator", "--connect", sim_ep,
                          "--connect", d_ep, "--exit-when-done"], work, hcc_log)
            procs.append(hcc)
            sim = _spawn(["sim", "--clock", "lockstep", "--vision", "fast", "--listen", sim_ep,
                          "--connect", d_ep, "--locations", str(spec.location), "--seed",
                          str(spec.seed), "--episode-duration", str(spec.time_limit),
                          "--results", "sim-results.json", "--wait-peers", "2"], work, sim_log)
            procs.append(sim)
            if sim.wait(300) != 0:
                raise RuntimeError(f"roger sim failed:\n{sim_log.read_text()}")
            if hcc.wait(60) != 0:
                raise RuntimeError(f"roger hcc failed:\n{hcc_log.read_text()}")
            status = _wait_idle(d_port)
            if _stop(daemon) != 0:
                raise RuntimeError(f"roger daemon failed:\n{daemon_log.read_text()}")
        finally:
            for p in procs:
                _stop(p)
        files = sorted((work / "recordings").glob("roger-aibo-*.mcap"))
        if len(files) != 1:
            raise RuntimeError(f"expected one session file, found {files}")
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(files[0], out)
        results = json.loads((work / "sim-results.json").read_text())
        episode = results["episodes"][0]
        return {"status": status, "outcome": episode["outcome"], "ticks": episode["ticks"]}
    finally:
        shutil.rmtree(work, ignore_errors=True)


def goldens(spec: Spec, rel: Path) -> tuple[dict[str, Any], str]:
    """Golden replay result and ``log info`` text of one recorded session (run from ROOT)."""
    from roger_daemon.cli import main as roger
    from roger_daemon.replay import replay_session
    from roger_daemon.replay.compare import REL_TOL, behaviour, probe_inputs

    res = replay_session(rel)
    if not res.bit_identical():
        raise RuntimeError(f"{rel}: replay does not reproduce the recording bit for bit: "
                           f"{json.dumps(res.summary(REL_TOL), default=str)[:2000]}")
    assert res.model is not None
    probes = probe_inputs([p.x for p in res.pairs], N_PROBES)
    golden = {
        "file": str(rel),
        "recorded_with": {"location": spec.location, "seed": spec.seed,
                          "time_limit_s": spec.time_limit, "vision": "fast",
                          "clock": "lockstep", "controller": "hcc --role demonstrator"},
        "tolerance": REL_TOL,
        "pairs_learned": len(res.pairs),
        "predictions_compared": len(res.diffs),
        "expert_labels": {str(k): v for k, v in sorted(res.expert_labels.items())},
        "first_ticks": [p.tick for p in res.pairs[:5]],
        "last_ticks": [p.tick for p in res.pairs[-5:]],
        "behaviour": behaviour(res.model, probes),
    }
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = roger(["log", "info", str(rel)])
    if code != 0:
        raise RuntimeError(f"roger log info {rel} exited {code}")
    return golden, buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", default=None, metavar="NAME",
                    help=f"only these sessions ({', '.join(s.name for s in SESSIONS)})")
    ap.add_argument("--goldens-only", action="store_true",
                    help="recompute the goldens from the committed files (no recording)")
    args = ap.parse_args(argv)
    os.chdir(ROOT)
    sys.path.insert(0, str(ROOT))
    from roger_daemon.blas import pin_blas_threads

    pin_blas_threads(1)  # as every roger command does (roger_daemon/blas.py)
    specs = [s for s in SESSIONS if not args.only or s.name in args.only]
    if not specs:
        ap.error(f"no session named {args.only}")
    for spec in specs:
        rel = DATA / f"{spec.name}.mcap"
        if not args.goldens_only:
            t0 = time.monotonic()
            got = record(spec, rel)
            print(f"{rel}: recorded in {time.monotonic() - t0:.1f} s: episode {got['outcome']} "
                  f"after {got['ticks']} ticks; daemon {got['status']}", flush=True)
        size = rel.stat().st_size
        if size > MAX_BYTES:
            print(f"{rel}: {size} bytes > {MAX_BYTES}: shorten the session", file=sys.stderr)
            return 1
        golden, info = goldens(spec, rel)
        (DATA / f"{spec.name}.golden.json").write_text(
            json.dumps(golden, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        (DATA / f"{spec.name}.info.txt").write_text(info, encoding="utf-8")
        print(f"{rel}: {size} bytes, {golden['pairs_learned']} pairs, "
              f"{golden['behaviour']['n_experts']} experts, "
              f"{golden['predictions_compared']} predictions reproduced; goldens written",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

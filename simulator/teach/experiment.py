"""``roger experiment teach``: the whole teaching loop measured, the teacher scripted.

Starts ``roger teach --clock lockstep`` (a subprocess: the page's server, the simulator, a
``roger daemon``), connects :class:`~simulator.teach.scripted.ScriptedTeacher` to the page's
own WebSocket and teaches as a person would, through the same channel:

1. ``--demonstrate-duration`` seconds of simulated time in demonstrate mode (episodes
   cycling through the 13 start locations);
2. ``--correct-duration`` seconds in correct mode (the robot drives, the teacher takes over
   where the robot's command disagrees with its own);
3. autonomous mode: the daemon's newest learned transitions loaded, then one episode
   from each of the 13 start locations (``--locations``), goals counted.

``OUT/results.json``: the pairs learned, the corrections (the page's and the daemon's
counts), per location the outcome, the goals, the wall times; ``OUT/session-0`` is the
``roger teach`` session (its MCAP log, checkpoints, daemon log). docs/teach.md reports a run.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from roger_daemon.tools.common import non_negative

__all__ = ["configure", "run", "start_teach"]

HZ = 30.0


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment teach``."""
    parser.add_argument("--out", type=Path, default=Path("runs/experiment-teach"),
                        metavar="DIR", help="output directory (default runs/experiment-teach)")
    parser.add_argument("--demonstrate-duration", dest="demonstrate_s", type=non_negative,
                        default=None, metavar="S",
                        help="simulated seconds of demonstration (default 600)")
    parser.add_argument("--correct-duration", dest="correct_s", type=non_negative,
                        default=None, metavar="S",
                        help="simulated seconds of correction after it (default 0)")
    for phase in ("demonstrate", "correct"):  # docs/cli.md: one word for a duration
        parser.add_argument(f"--{phase}-minutes", dest=f"{phase}_minutes", type=non_negative,
                            default=None, metavar="M",
                            help=f"deprecated: the same in minutes (use --{phase}-duration S)")
    parser.add_argument("--locations", default="all",
                        help="the evaluation's start locations (default all 13)")
    parser.add_argument("--episode-duration", dest="time_limit", type=non_negative,
                        default=60.0, metavar="S",
                        help="simulated seconds per episode (default 60, the goal-scoring "
                             "experiment's)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the session")


def start_teach(out: Path, *extra: str, timeout_s: float = 180.0
                ) -> tuple[subprocess.Popen[bytes], str]:
    """``roger teach`` on a free port writing ``out`` (its output in ``out/teach.log``): the
    process and the page's address."""
    from simulator.experiment.procs import child_env, roger_argv

    log_path = out / "teach.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(roger_argv("teach", "--http", "127.0.0.1:0", "--out", str(out),
                                           *extra),
                                stdout=log, stderr=subprocess.STDOUT, env=child_env())
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and proc.poll() is None:
        m = re.search(r"the page is at (http://\S+/)", log_path.read_text("utf-8", "replace"))
        if m:
            return proc, m.group(1)
        time.sleep(0.2)
    if proc.poll() is None:
        proc.kill()
        proc.wait(30)
    tail = log_path.read_text("utf-8", "replace")[-3000:]
    raise RuntimeError(f"roger teach did not serve its page (see {log_path}):\n{tail}")


def stop_teach(proc: subprocess.Popen[bytes], timeout_s: float = 120.0) -> int:
    """Ctrl-C to ``roger teach``; its exit code (killed after ``timeout_s``: -9)."""
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(30)


def _daemon(state: dict[str, Any]) -> dict[str, Any]:
    d: dict[str, Any] = state.get("daemon", {})
    return d


def _teach(url: str, args: argparse.Namespace, locations: list[int]) -> dict[str, Any]:
    from simulator.teach.scripted import ScriptedTeacher

    teacher = ScriptedTeacher(url)
    times: dict[str, float] = {}
    try:
        t0 = time.monotonic()
        teacher.until(lambda m: m.get("type") == "state")
        if args.demonstrate_s > 0:
            teacher.teach("demonstrate", round(args.demonstrate_s * HZ))
        times["demonstrate_s"] = time.monotonic() - t0
        if args.correct_s > 0:
            t1 = time.monotonic()
            teacher.teach("correct", round(args.correct_s * HZ))
            times["correct_s"] = time.monotonic() - t1
        t2 = time.monotonic()
        fitted = teacher.wait_transitions()
        times["load_transitions_s"] = time.monotonic() - t2
        t3 = time.monotonic()
        episodes = teacher.evaluate(locations)
        times["evaluate_s"] = time.monotonic() - t3
        state = teacher.state
    finally:
        teacher.close()
    goals = sum(e["outcome"] == "goal" for e in episodes)
    d = _daemon(state)
    return {
        "goals": goals, "trials": len(episodes),
        "target": "goals from >= 8 of the 13 start locations",
        "per_location": [{"location": e["location"], "outcome": e["outcome"],
                          "sim_time_s": e["sim_time_s"]} for e in episodes],
        "pairs_learned": d.get("updates"), "experts": d.get("experts"),
        "pairs_teacher": d.get("pairs_teacher"), "corrections_daemon": d.get("corrections"),
        "teacher": dict(teacher.counts), "transitions": fitted.get("fsm", {}),
        "page_counts": state.get("counts", {}), "refused": state.get("refused", {}),
        "wall_s": {k: round(v, 1) for k, v in times.items()},
    }


def phase_durations(args: argparse.Namespace) -> None:
    """``args.demonstrate_s`` and ``args.correct_s`` in seconds, from ``--PHASE-duration`` or
    the deprecated ``--PHASE-minutes`` (not both); ``UsageError`` naming the clash."""
    from roger_daemon.tools.common import UsageError

    for phase, default in (("demonstrate", 600.0), ("correct", 0.0)):
        seconds, minutes = getattr(args, f"{phase}_s"), getattr(args, f"{phase}_minutes")
        if seconds is not None and minutes is not None:
            raise UsageError(f"give --{phase}-duration S or the deprecated --{phase}-minutes "
                             f"M, not both (got {seconds:g} s and {minutes:g} min)")
        setattr(args, f"{phase}_s", default if seconds is None and minutes is None
                else seconds if minutes is None else minutes * 60.0)


def run(args: argparse.Namespace) -> int:
    """Teach, evaluate, write ``OUT/results.json``; 0, or 1 if the session failed."""
    from simulator.episodes import parse_locations

    phase_durations(args)
    try:
        locations = parse_locations(args.locations)
    except ValueError as exc:
        print(f"roger experiment teach: --locations: {exc}", file=sys.stderr)
        return 2
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    proc, url = start_teach(out, "--clock", "lockstep", "--vision", "fast", "--seed",
                            str(args.seed), "--episode-duration", repr(float(args.time_limit)))
    try:
        result = _teach(url, args, locations)
    finally:
        code = stop_teach(proc)
    result.update({"settings": {"demonstrate_s": args.demonstrate_s,
                                "correct_s": args.correct_s,
                                "episode_duration_s": args.time_limit, "seed": args.seed,
                                "clock": "lockstep", "vision": "fast"},
                   "teach_exit": code})
    (out / "results.json").write_text(json.dumps(result, indent=1) + "\n", "utf-8")
    print(json.dumps({k: result[k] for k in ("goals", "trials", "pairs_learned", "experts",
                                             "corrections_daemon", "wall_s")}))
    if code != 130:
        print(f"roger experiment teach: roger teach exited {code}; see {out / 'teach.log'}",
              file=sys.stderr)
        return 1
    return 0

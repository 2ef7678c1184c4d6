"""``roger bench sim``: simulator speed and the hand-coded controller's success.

1. ``ticks_per_s``: ``roger sim --clock lockstep`` (rendered 208x160 camera) and ``roger hcc``
   as two subprocesses over Zenoh on 127.0.0.1, one shot from each of the 13 locations;
   ticks of the whole run divided by its wall time (episode resets included). The same run
   gives ``hcc_success_rate`` (one shot per location, as in the paper's 69 % baseline).
2. ``fast_ticks_per_s``: the same with ``--vision fast`` (analytic projection + ray casts);
   also ``hcc_success_rate_fast``.
3. In-process (no Zenoh, fast vision) over ``--seeds`` seeds x 13 locations: the success rate
   with a Wilson 95 % interval, the outcome counts (failure modes), mean time to goal, and the
   aliasing report (:func:`simulator.aliasing.measure_aliasing`) of that demonstration data.

Timings depend on the machine and its load: the JSON records the CPU count and load average.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from typing import Any

import numpy as np

from roger_daemon.machine import finish, machine_record

__all__ = ["configure", "free_port", "run", "run_processes"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger bench sim``."""
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--seed", type=int, default=0, help="seed of the Zenoh runs")
    parser.add_argument("--locations", default="all", help="locations of the Zenoh runs")
    parser.add_argument(
        "--seeds", type=int, default=3, help="in-process seeds for the success estimate (0: skip)"
    )
    parser.add_argument("--skip-rendered", action="store_true", help="skip the rendered run")
    parser.add_argument("--timeout", type=float, default=900.0, help="per Zenoh run, seconds")


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free right now (:func:`roger_daemon.harness.free_port`)."""
    from roger_daemon.harness import free_port as harness_free_port

    return harness_free_port()


def _roger() -> list[str]:
    return [sys.executable, "-m", "roger_daemon"]


def run_processes(
    sim_args: list[str], hcc_args: list[str] | None = None, timeout: float = 900.0
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Start ``roger hcc`` then ``roger sim`` (lockstep) on a free port; return both JSONs.

    The controller exits by itself when the simulator's run is complete.
    """
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "ROGER_LOG_LEVEL": os.environ.get("ROGER_LOG_LEVEL", "WARNING")}
    hcc = subprocess.Popen(
        [
            *_roger(),
            "hcc",
            "--connect",
            ep,
            "--exit-when-done",
            "--idle-exit",
            "60",
            *(hcc_args or []),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        sim = subprocess.run(
            [
                *_roger(),
                "sim",
                "--listen",
                ep,
                "--connect",
                "none",
                "--clock",
                "lockstep",
                *sim_args,
            ],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=env,
        )
        hcc_out, hcc_err = hcc.communicate(timeout=30)
    finally:
        if hcc.poll() is None:
            hcc.terminate()
            try:
                hcc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                hcc.kill()
    if sim.returncode != 0:
        raise RuntimeError(f"roger sim failed ({sim.returncode}): {sim.stderr[-2000:]}")
    sim_json = json.loads(sim.stdout.strip().splitlines()[-1])
    lines = hcc_out.strip().splitlines()
    hcc_json = json.loads(lines[-1]) if lines else {"error": hcc_err[-2000:]}
    return sim_json, hcc_json


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion."""
    if n == 0:
        return (0.0, 1.0)
    ph = k / n
    den = 1 + z * z / n
    c = (ph + z * z / (2 * n)) / den
    h = z * math.sqrt(ph * (1 - ph) / n + z * z / (4 * n * n)) / den
    return (max(0.0, c - h), min(1.0, c + h))


def _inprocess(seeds: int) -> dict[str, Any]:
    from simulator.aliasing import measure_aliasing
    from simulator.controllers.hcc import HCC, LABELS
    from simulator.episodes import START_LOCATIONS, SoccerSim, Trace, run_episode

    sim = SoccerSim(vision="fast")
    hcc = HCC()
    outcomes: dict[str, int] = {}
    per_loc = np.zeros(len(START_LOCATIONS))
    goal_times = []
    xs, ys, labs, eps, tks = [], [], [], [], []
    n = k = 0
    t0 = time.perf_counter()
    ticks = 0
    counters: dict[str, int] = {}
    for seed in range(seeds):
        for loc in range(len(START_LOCATIONS)):
            tr = Trace()
            res = run_episode(sim, hcc, loc, seed, trace=tr, episode=n)
            outcomes[res.outcome] = outcomes.get(res.outcome, 0) + 1
            for key, v in res.counters.items():
                counters[key] = counters.get(key, 0) + v
            if res.success:
                k += 1
                per_loc[loc] += 1
                goal_times.append(res.sim_time_s)
            X, Y, L = tr.arrays()
            xs.append(X)
            ys.append(Y)
            labs.append(L)
            eps.append(np.full(len(X), n))
            tks.append(np.arange(len(X)))
            ticks += res.ticks
            n += 1
    wall = time.perf_counter() - t0
    sim.close()
    alias = measure_aliasing(
        np.concatenate(xs),
        np.concatenate(ys),
        np.concatenate(labs),
        np.concatenate(eps),
        np.concatenate(tks),
    )
    labels = np.concatenate(labs)
    lo, hi = wilson(k, n)
    return {
        "seeds": seeds,
        "episodes": n,
        "success_rate": k / n if n else 0.0,
        "success_ci95": [round(lo, 3), round(hi, 3)],
        "outcomes": outcomes,
        "per_location_success": (per_loc / max(seeds, 1)).round(3).tolist(),
        "mean_time_to_goal_s": round(float(np.mean(goal_times)), 2) if goal_times else None,
        "motion_counters": counters,
        "subtask_fractions": {
            s: round(float(np.mean(labels == s)), 4) for s in LABELS
        },
        "inprocess_fast_ticks_per_s": round(ticks / wall, 1),
        "aliasing": alias,
    }


def run(args: argparse.Namespace) -> int:
    """Run the benchmark; print a table or one JSON object."""
    out: dict[str, Any] = {
        "bench": "sim",
        "machine": machine_record(),
    }
    common = ["--locations", args.locations, "--seed", str(args.seed)]
    if not args.skip_rendered:
        sim_j, hcc_j = run_processes(common, timeout=args.timeout)
        s = sim_j["summary"]
        out["ticks_per_s"] = s["ticks_per_s"]
        out["hcc_success_rate"] = s["success_rate"]
        out["rendered"] = {
            "camera": sim_j["camera"],
            "outcomes": s["outcomes"],
            "ticks": s["ticks"],
            "wall_s": s["wall_s"],
            "command_timeouts": s["command_timeouts"],
            "per_episode": [
                {k: e[k] for k in ("location", "outcome", "sim_time_s")} for e in sim_j["episodes"]
            ],
            "hcc_subtask_ticks": hcc_j.get("subtask_ticks"),
        }
    sim_j, _ = run_processes([*common, "--vision", "fast"], timeout=args.timeout)
    s = sim_j["summary"]
    out["fast_ticks_per_s"] = s["ticks_per_s"]
    out["hcc_success_rate_fast"] = s["success_rate"]
    out["fast"] = {
        "outcomes": s["outcomes"],
        "ticks": s["ticks"],
        "wall_s": s["wall_s"],
        "command_timeouts": s["command_timeouts"],
    }
    if args.seeds > 0:
        out["inprocess"] = _inprocess(args.seeds)
    finish(out["machine"])
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"ticks_per_s (lockstep, rendered 208x160, Zenoh): {out.get('ticks_per_s', 'skipped')}")
    print(f"fast_ticks_per_s (lockstep, fast vision, Zenoh):  {out['fast_ticks_per_s']}")
    print(f"hcc_success_rate (13 locations, one shot):        {out.get('hcc_success_rate')}")
    print(f"hcc_success_rate_fast:                            {out['hcc_success_rate_fast']}")
    if "inprocess" in out:
        ip = out["inprocess"]
        print(
            f"in-process success over {ip['episodes']} episodes: {ip['success_rate']:.3f} "
            f"(95% CI {ip['success_ci95']}), outcomes {ip['outcomes']}"
        )
        al = ip["aliasing"]
        print(
            f"aliasing: {al['pairs']} near-identical pairs, {al['conflict_fraction']:.3f} "
            f"conflicting; across subtasks {al['cross_subtask_pairs']} pairs, "
            f"{al['cross_subtask_conflict_fraction']:.3f} conflicting"
        )
        for pair, v in al["per_subtask_pair"].items():
            print(f"  {pair:10s} pairs {v['pairs']:6d}  conflicting {v['fraction']:.3f}")
    print(f"machine: {out['machine']}")
    return 0

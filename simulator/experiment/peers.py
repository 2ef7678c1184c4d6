"""``roger experiment peers``: LeRobot's ACT and Diffusion Policy on goal-scoring's demonstrations.

1. **Demonstrations**: ``roger experiment goal-scoring``'s, from the same plan (``--seed``,
   start locations, shots, episode limit, vision) and its downsampling's kept indices
   (:mod:`simulator.experiment.peers_data`).
2. **Export**: every demonstrated tick through ROGER's LeRobot v3 export, ``OUT/dataset``.
3. **Training**: each policy with LeRobot's own classes on CPU, for ``--steps`` optimizer steps
   of ``--batch-size`` samples starting at the downsampled points (``--frames all``: at any
   tick) (:mod:`simulator.experiment.peers_policy`); ``OUT/models/NAME`` in LeRobot's format.
4. **Evaluation**: each policy alone (no HCC) in the same simulator, from the start locations
   (``--attempts`` each, goal-scoring's evaluation seeds) and the held-out poses; the HCC too,
   for the ratio.
5. **Learning curve** (``--curve``): each policy retrained on the first N demonstrations
   (round-robin over the locations), ROGER learning the same points in one pass and evaluated
   after each N (experts + HCC transitioner, and learned transitions alone);
   ``OUT/learning_curve.png``.
6. ``OUT/results.json`` (:mod:`simulator.experiment.peers_report`).

docs/peers.md has the protocol, the settings and the measured results.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DEFAULT_STEPS", "configure", "parse_curve", "run"]

#: Optimizer steps per policy (the CPU budget, docs/peers.md "Budget"); LeRobot's default is
#: 100,000 steps of batch 8 (``TrainPipelineConfig``), GPU hours.
DEFAULT_STEPS = {"act": 1500, "diffusion": 1500}
DEFAULT_CURVE = "10,20,40,80,130"
SMOKE_STEPS = 4


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment peers``."""
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    parser.add_argument("--seed", type=int, default=0,
                        help="master seed, as goal-scoring's --seed (default 0)")
    parser.add_argument("--policies", default="act,diffusion",
                        help="LeRobot policies to train and evaluate (default act,diffusion)")
    parser.add_argument("--steps", default=None, metavar="N|act=N,diffusion=M",
                        help="optimizer steps per policy (default "
                        + ",".join(f"{k}={v}" for k, v in DEFAULT_STEPS.items()) + ")")
    parser.add_argument("--batch-size", type=int, default=8,
                        help="samples per step (default 8, LeRobot's)")
    parser.add_argument("--frames", choices=("downsampled", "all"), default="downsampled",
                        help="ticks a training sample starts at: goal-scoring's downsampled "
                        "points (default) or every demonstrated tick")
    parser.add_argument("--curve", default=DEFAULT_CURVE, metavar="N,N,...|none",
                        help=f"learning-curve points, in demonstrations (default {DEFAULT_CURVE})")
    parser.add_argument("--curve-attempts", type=int, default=1,
                        help="attempts per location at each curve point (default 1)")
    parser.add_argument("--attempts", type=int, default=None,
                        help="evaluation attempts per location (default 3)")
    parser.add_argument("--locations", default=None, help="start locations (default all)")
    parser.add_argument("--shots", type=int, default=None,
                        help="demonstrations per location (default 10, goal-scoring's)")
    parser.add_argument("--per-subtask", type=int, default=None,
                        help="downsampling limit per subtask (default 1000)")
    parser.add_argument("--episode-duration", dest="time_limit", type=float, default=None,
                        metavar="S", help="simulated seconds per episode (default 60)")
    parser.add_argument("--start-poses", default="default", metavar="FILE|none",
                        help="held-out start poses (default the shipped "
                        "configs/held-out-poses.toml; 'none' skips them)")
    parser.add_argument("--threads", type=int, default=2,
                        help="torch threads for training (inference always uses 1)")
    parser.add_argument("--smoke", action="store_true",
                        help=f"tiny run: 2 locations, 1 shot, 20 s episodes, {SMOKE_STEPS} "
                        "steps, curve 1,2")


def parse_curve(text: str, total: int) -> list[int]:
    """``"10,20,130"`` -> the curve's points, each capped at ``total``; ``"none"`` -> [].

    >>> parse_curve("10,20,40,80,130", 26)
    [10, 20, 26]
    """
    if text.strip().lower() == "none":
        return []
    try:
        points = [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise ValueError(f"--curve must be numbers like '10,20,40' or 'none', got {text!r}"
                         ) from None
    if not points or min(points) < 1:
        raise ValueError(f"--curve points must be >= 1, got {text!r}")
    return sorted({min(p, total) for p in points})


def parse_steps(text: str | None, policies: list[str]) -> dict[str, int]:
    """``--steps``: one number for every policy, or ``act=N,diffusion=M``.

    >>> parse_steps("act=10,diffusion=20", ["act", "diffusion"])
    {'act': 10, 'diffusion': 20}
    """
    steps = {p: DEFAULT_STEPS[p] for p in policies}
    if text is None:
        return steps
    try:
        if "=" not in text:
            return {p: _positive(int(text)) for p in policies}
        for part in text.split(","):
            name, _, value = part.partition("=")
            if name.strip() not in steps:
                raise ValueError
            steps[name.strip()] = _positive(int(value))
    except ValueError:
        raise ValueError(f"--steps must be N or act=N,diffusion=M with N >= 1, got {text!r}"
                         ) from None
    return steps


def _positive(n: int) -> int:
    if n < 1:
        raise ValueError(n)
    return n


def _plan(args: argparse.Namespace) -> Any:
    """goal-scoring's plan for the same demonstrations and evaluation seeds."""
    from simulator.experiment.goal_plan import plan_from_args

    quick = bool(args.smoke)
    ns = argparse.Namespace(
        out=args.out, quick=quick, seed=args.seed, jobs=1, locations=args.locations,
        attempts=args.attempts, per_subtask=args.per_subtask, time_limit=args.time_limit,
        vision=None, controllers="hcc,roger,autonomous", daemon_check=False, config=None,
        overrides=[], task_config=None, retries=0, resume=False, shots=args.shots,
        learner_seeds=1, rule=None, preset=None, in_process=True, start_poses=None,
        streams=None)
    from simulator.controllers.transitioner import DEFAULT_RULE

    ns.rule = DEFAULT_RULE
    return plan_from_args(ns)


def _starts(spec: str) -> tuple[str | None, list[Any] | None]:
    if spec == "none":
        return None, None
    from simulator.experiment.start_poses import load_start_poses

    path = (str(Path(__file__).resolve().parents[2] / "configs" / "held-out-poses.toml")
            if spec == "default" else spec)
    if spec == "default" and not Path(path).is_file():
        from importlib.resources import files

        path = str(files("roger_daemon") / "configs" / "held-out-poses.toml")
    return path, load_start_poses(path)


def run(args: argparse.Namespace) -> int:
    """Run the comparison; 0 on success, 2 on a bad argument or without the peers extra."""
    from simulator.experiment.peers_policy import POLICIES, available

    try:
        policies = [p.strip() for p in args.policies.split(",") if p.strip()]
        bad = [p for p in policies if p not in POLICIES]
        if bad or not policies:
            raise ValueError(f"--policies must name some of {', '.join(POLICIES)}, got "
                             f"{args.policies!r}")
        steps = parse_steps(args.steps, policies)
        if args.smoke:
            steps = {p: SMOKE_STEPS for p in policies}
        if args.batch_size < 1 or args.curve_attempts < 1 or args.threads < 1:
            raise ValueError("--batch-size, --curve-attempts and --threads must be >= 1, got "
                             f"{args.batch_size}, {args.curve_attempts}, {args.threads}")
        plan = _plan(args)
        curve = parse_curve("1,2" if args.smoke else args.curve,
                            len(plan.locations) * plan.shots)
        poses_file, starts = _starts(args.start_poses)
    except ValueError as exc:
        print(f"roger experiment peers: {exc}", file=sys.stderr)
        return 2
    why = available()
    if why:
        print(f"roger experiment peers: {why}", file=sys.stderr)
        return 2
    from simulator.experiment.peers_run import PeersRun

    return PeersRun(plan, policies, steps, args, curve, poses_file, starts).run()


def percentiles_ms(times_s: list[float]) -> dict[str, float]:
    """p50 and p99 of per-tick times, in ms."""
    if not times_s:
        return {"infer_p50_ms": float("nan"), "infer_p99_ms": float("nan")}
    a = np.asarray(times_s) * 1e3
    return {"infer_p50_ms": round(float(np.percentile(a, 50)), 3),
            "infer_p99_ms": round(float(np.percentile(a, 99)), 3)}


def now() -> float:
    """Monotonic seconds (phases' wall times)."""
    return time.monotonic()

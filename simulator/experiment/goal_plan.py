"""The plan of ``roger experiment goal-scoring``: its arguments, defaults and derived seeds.

:func:`configure` declares the command line and :func:`plan_from_args` resolves it (quick
presets, defaults, checks) into a :class:`Plan`, everything a run does
(docs/goal-scoring.md); :mod:`simulator.experiment.goal_scoring` runs it.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from simulator.controllers.transitioner import DEFAULT_RULE, RULES

__all__ = ["CONTROLLERS", "DEFAULT_TIME_LIMIT", "GATES", "Plan", "configure", "derived_seeds",
           "plan_from_args"]

CONTROLLERS = ("hcc", "roger", "dpa", "oracle", "groups", "autonomous")
#: The gates the ``roger`` and ``autonomous`` rows choose experts by (``--gates``): ``niw``,
#: each expert's own NIW gate (paper Algorithm 2); ``split``, each expert's gate split where
#: its inputs form clusters, without labels (roger_daemon/gate_split.py, docs/goal-scoring.md)
GATES = ("niw", "split")
#: Defaults of the full run (docs/goal-scoring.md says why they differ from the paper's).
DEFAULT_SHOTS = 10
DEFAULT_TIME_LIMIT = 60.0
DEFAULT_VISION = "fast"
#: The task's learner settings on top of the daemon's default preset (docs/goal-scoring.md):
#: the broad kernel of the default preset needs a coarser novelty test, else K_B becomes
#: ill-conditioned and a GP trained on one subtask's 1000 points returns NaN. 100 particles:
#: the particle filter keeps more partitions alive and more often gives every subtask its own
#: experts (docs/goal-scoring.md: merged groups over 4 demonstration streams x 3 learner
#: seeds, 91/156 goals with 30 particles, 117/156 with 100).
TASK_LEARNER_OVERRIDES = ("learner.novelty_threshold=1e-3", "learner.particles=100")
#: Offsets of the derived seeds (all derived from ``--seed``; every one is in results.json).
_EVAL_SEED_OFFSET = 1_000_003


@dataclass(frozen=True)
class Plan:
    """Everything a run does, resolved from the command line (quick presets applied)."""

    out: Path
    seed: int
    jobs: int
    quick: bool
    locations: tuple[int, ...]
    attempts: int
    per_subtask: int
    time_limit: float
    vision: str
    daemon_check: bool
    controllers: tuple[str, ...]
    config: str | None
    overrides: tuple[str, ...]
    task_config: str | None
    retries: int = 1
    resume: bool = False
    seeds: dict[str, int] = field(default_factory=dict)
    shots: int = 1
    learner_seeds: int = 1
    rule: str = DEFAULT_RULE
    in_process: bool = False
    start_poses: str | None = None
    preset: str | None = None
    streams: tuple[int, ...] = ()
    gates: str = "niw"
    demo_noise: float = 0.0

    def to_json(self) -> dict[str, Any]:
        """The plan as plain JSON (paths as strings)."""
        d = asdict(self)
        d["out"] = str(self.out)
        d["locations"] = list(self.locations)
        d["controllers"] = list(self.controllers)
        d["overrides"] = list(self.overrides)
        d["streams"] = list(self.streams)
        return d


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment goal-scoring``."""
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    parser.add_argument("--quick", action="store_true",
                        help="small version for CI: 2 locations, 1 attempt, 150 points per "
                        "subtask, 20 s episodes, fast vision (each can still be overridden)")
    parser.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    parser.add_argument("--jobs", type=int, default=0,
                        help="parallel episode jobs (default: number of cores)")
    parser.add_argument("--locations", default=None,
                        help="start locations, e.g. 'all', '0,3,7', '0-4' (default all)")
    parser.add_argument("--attempts", type=int, default=None,
                        help="evaluation attempts per location and controller (default 3)")
    parser.add_argument("--per-subtask", type=int, default=None,
                        help="downsample to at most this many points per subtask (default 1000)")
    parser.add_argument("--episode-duration", "--time-limit", dest="time_limit", type=float,
                        default=None, metavar="S",
                        help=f"simulated seconds per episode (default {DEFAULT_TIME_LIMIT:g}; the "
                        "paper's was 150; --time-limit: the deprecated spelling)")
    parser.add_argument("--vision", choices=("rendered", "fast"), default=None,
                        help=f"simulator vision (default {DEFAULT_VISION})")
    parser.add_argument("--controllers", default=",".join(CONTROLLERS),
                        help="controllers to evaluate (default all: "
                        + ",".join(CONTROLLERS) + ")")
    parser.add_argument("--no-daemon-check", dest="daemon_check", action="store_false",
                        help="skip feeding the stream to a daemon and replaying its log")
    parser.add_argument("--config", default=None,
                        help="daemon TOML whose [learner] table sets the parameters "
                        "(default: the paper's)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="learner.KEY=VALUE", help="override one learner parameter")
    parser.add_argument("--task-config", default=None,
                        help="task TOML for roger sim / roger hcc (e.g. configs/aibo.toml)")
    parser.add_argument("--retries", type=int, default=1,
                        help="re-run a job whose processes failed this many times")
    parser.add_argument("--resume", action="store_true",
                        help="reuse the results of jobs already finished in OUT with the same "
                        "settings and model (e.g. after an interruption)")
    parser.add_argument("--shots", type=int, default=None,
                        help="demonstrations per start location (default 10; --quick: 1)")
    parser.add_argument("--learner-seeds", type=int, default=None,
                        help="ROGER models trained with seeds SEED..SEED+N-1, each evaluated "
                        "(default 3; --quick: 1)")
    parser.add_argument("--rule", choices=RULES, default=DEFAULT_RULE,
                        help="transitioner rule among the subtask's experts (default "
                        f"{DEFAULT_RULE})")
    parser.add_argument("--gates", choices=GATES, default="niw",
                        help="how the roger and autonomous rows choose among the experts: niw "
                        "(each expert's gate, paper Algorithm 2; default) or split (each gate "
                        "split where its inputs form clusters, label-free; on the Zenoh path "
                        "the daemon serves them as a one-particle ROGER model)")
    parser.add_argument("--demo-noise", type=float, default=0.0, metavar="F",
                        help="the demonstrator's executed walking and head commands disturbed "
                        "by F x each range (held 0.5 s), its own commands learned; 0 = the "
                        "paper's protocol (default); on the Zenoh path roger hcc "
                        "--demo-noise, drawn per start location")
    parser.add_argument("--preset", default=None,
                        help="learner preset (e.g. 'paper': the paper's literal numbers, every "
                        "lever off); same as --set learner.preset=NAME")
    parser.add_argument("--in-process", action="store_true",
                        help="demonstrate, train and evaluate in this process, no Zenoh (fast "
                        "path for iteration; the Zenoh path is the reference)")
    parser.add_argument("--start-poses", default=None, metavar="FILE",
                        help="also evaluate HCC, oracle and ROGER from these start poses "
                        "(TOML or JSON, docs/goal-scoring.md), in-process")
    parser.add_argument("--streams", default=None, metavar="LIST",
                        help="run these demonstration streams (e.g. '0-4'; stream S is --seed "
                        "S) with one configuration, in-process, and report them side by side: "
                        "settings chosen on 0-2, the rest validation (docs/goal-scoring.md)")
    parser.add_argument("--plan", action="store_true", help="print the resolved plan and exit")


def plan_from_args(args: argparse.Namespace) -> Plan:
    """Resolve quick presets and defaults; raise ``ValueError`` on bad values."""
    from simulator.episodes import parse_locations

    quick = bool(args.quick)
    locations = parse_locations(args.locations or ("0,6" if quick else "all"))
    shots = args.shots if args.shots is not None else (1 if quick else DEFAULT_SHOTS)
    learner_seeds = (args.learner_seeds if args.learner_seeds is not None
                     else (1 if quick else 3))
    if shots < 1 or learner_seeds < 1:
        raise ValueError(f"--shots and --learner-seeds must be >= 1, got {shots} and "
                         f"{learner_seeds}")
    overrides = list(args.overrides)
    if args.preset != "paper":
        overrides[:0] = list(TASK_LEARNER_OVERRIDES)
    if args.preset is not None:
        overrides.insert(0, f"learner.preset={args.preset}")
    attempts = args.attempts if args.attempts is not None else (1 if quick else 3)
    per_subtask = args.per_subtask if args.per_subtask is not None else (150 if quick else 1000)
    time_limit = (args.time_limit if args.time_limit is not None
                  else (20.0 if quick else DEFAULT_TIME_LIMIT))
    vision = args.vision or ("fast" if quick else DEFAULT_VISION)
    controllers = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
    bad = [c for c in controllers if c not in CONTROLLERS]
    if bad:
        raise ValueError(f"unknown controller(s) {bad}; choose from {list(CONTROLLERS)}")
    if attempts < 1 or per_subtask < 1 or time_limit <= 0:
        raise ValueError("--attempts and --per-subtask must be >= 1, --episode-duration > 0")
    for o in overrides:
        if not o.startswith("learner."):
            raise ValueError(f"--set {o!r}: only learner.KEY=VALUE overrides are used here")
    jobs = args.jobs if args.jobs and args.jobs > 0 else (os.cpu_count() or 1)
    seed = int(args.seed)
    seeds = derived_seeds(seed)
    from simulator.experiment.streams import parse_streams

    streams = parse_streams(args.streams) if args.streams else ()
    gates = getattr(args, "gates", "niw")
    demo_noise = float(getattr(args, "demo_noise", 0.0))
    if not 0.0 <= demo_noise <= 0.5:
        raise ValueError(f"--demo-noise {demo_noise!r}: must be in [0, 0.5] (a fraction of "
                         "each command's range)")
    return Plan(
        out=Path(args.out), seed=seed, jobs=jobs, quick=quick, locations=tuple(locations),
        attempts=attempts, per_subtask=per_subtask, time_limit=float(time_limit),
        vision=vision, daemon_check=bool(args.daemon_check), controllers=controllers,
        config=args.config, overrides=tuple(overrides), task_config=args.task_config,
        retries=max(0, int(args.retries)), resume=bool(args.resume), seeds=seeds,
        shots=shots, learner_seeds=learner_seeds, rule=args.rule,
        in_process=bool(args.in_process) or bool(streams), start_poses=args.start_poses,
        preset=args.preset, streams=streams, gates=gates, demo_noise=demo_noise,
    )


def derived_seeds(seed: int) -> dict[str, int]:
    """Every seed of a run, derived from ``--seed`` (all of them go to results.json)."""
    return {"master": seed, "demo_sim": seed, "downsample": seed, "learner": seed,
            "eval_sim": seed + _EVAL_SEED_OFFSET}

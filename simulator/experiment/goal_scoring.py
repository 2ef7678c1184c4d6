"""``roger experiment goal-scoring``: the paper's section IV, end to end.

1. **Demonstrations**: the HCC demonstrator from each start location, one shot each, failures
   included; ``roger sim`` + ``roger hcc --role demonstrator`` + ``roger record`` per location,
   talking over Zenoh on private loopback ports; one MCAP file per location.
2. **Downsampling**: at most ``--per-subtask`` (1000) random points per subtask, order kept
   (seeded).
3. **Training**: ROGER learns the stream incrementally (paper parameters unless ``--config`` /
   ``--set learner.X=V``); the same stream is fed to a real daemon in lockstep and its log
   replayed offline, and the three models must be identical (``--no-daemon-check`` skips it).
4. **Grouping**: each expert takes the subtask that generated the majority of its data.
5. **Evaluation**, ``--attempts`` (3) from each location: ``hcc`` (the HCC itself), ``roger``
   (the daemon in predict mode resumed from the trained model's checkpoint + ``roger hcc
   --role transitioner``), ``dpa`` (the daemon serving the unimap baseline trained on the same
   data + ``roger experiment dpa``, which executes each prediction's mean).
6. **Report**: success rates with Wilson 95 % intervals, ratio roger/hcc, experts, purity, ARI,
   NMI, per-subtask shares, timings; a table on the terminal and ``OUT/results.json``.
7. **Figures** (PNG in OUT): Fig. 7a-c, Fig. 8, success per start location.

Episodes are deterministic given the seeds (lockstep); independent jobs run in parallel
(``--jobs``). ``--quick`` is a small version of the same pipeline for CI.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from roger_daemon.atomic import write_json
from roger_daemon.machine import machine_record
from simulator.controllers.transitioner import DEFAULT_RULE, RULES
from simulator.experiment.jobs import EpisodeJob
from simulator.experiment.runner import json_default, machine

__all__ = ["CONTROLLERS", "PAPER", "Plan", "configure", "derived_seeds", "plan_from_args",
           "run"]

CONTROLLERS = ("hcc", "roger", "dpa", "oracle", "groups", "autonomous")
CONTROLLER_NAMES = {
    "hcc": "HCC (hand-coded controller)",
    "oracle": "segmentation oracle (GP per true subtask)",
    "roger": "ROGER experts + HCC transitioner",
    "dpa": "unimap GP (DPA)",
    "groups": "ROGER experts merged per group + HCC transitioner",
    "autonomous": "ROGER experts + learned transitions (no HCC)",
}
#: The paper's numbers (section IV.A): success rates, experts, ratio learned/HCC.
PAPER = {"hcc": 0.69, "roger": 0.31, "dpa": 0.0, "experts": 85, "ratio": 0.45}
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
#: Start locations per evaluation job (one simulator, controller and daemon run them all):
#: each job's processes cost a few seconds to start and stop, so fewer, longer jobs; an
#: episode does not depend on the job it runs in (``paths_agree`` compares episode by episode).
EVAL_LOCATIONS_PER_JOB = 5
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
    return Plan(
        out=Path(args.out), seed=seed, jobs=jobs, quick=quick, locations=tuple(locations),
        attempts=attempts, per_subtask=per_subtask, time_limit=float(time_limit),
        vision=vision, daemon_check=bool(args.daemon_check), controllers=controllers,
        config=args.config, overrides=tuple(overrides), task_config=args.task_config,
        retries=max(0, int(args.retries)), resume=bool(args.resume), seeds=seeds,
        shots=shots, learner_seeds=learner_seeds, rule=args.rule,
        in_process=bool(args.in_process) or bool(streams), start_poses=args.start_poses,
        preset=args.preset, streams=streams,
    )


def derived_seeds(seed: int) -> dict[str, int]:
    """Every seed of a run, derived from ``--seed`` (all of them go to results.json)."""
    return {"master": seed, "demo_sim": seed, "downsample": seed, "learner": seed,
            "eval_sim": seed + _EVAL_SEED_OFFSET}


def learner_params(plan: Plan) -> Any:
    """The learner parameters: the paper's, then ``--config``'s [learner], then ``--set``."""
    from roger_daemon.config import load_config

    cfg = load_config(plan.config, list(plan.overrides))
    return cfg.robots[0].params


# --- the phases -------------------------------------------------------------------------


def _demo_jobs(plan: Plan) -> list[EpisodeJob]:
    return [
        EpisodeJob("demo", (loc,), plan.shots, plan.seeds["demo_sim"], plan.time_limit,
                   plan.vision, plan.out / "work" / "demo" / f"loc-{loc:02d}",
                   task_config=plan.task_config)
        for loc in plan.locations
    ]


def location_chunks(locations: tuple[int, ...], size: int) -> list[tuple[int, ...]]:
    """``locations`` in consecutive chunks of at most ``size``, as even as possible.

    >>> location_chunks(tuple(range(13)), 5)
    [(0, 1, 2, 3), (4, 5, 6, 7, 8), (9, 10, 11, 12)]
    """
    n = max(1, -(-len(locations) // size))
    bounds = [round(i * len(locations) / n) for i in range(n + 1)]
    return [locations[a:b] for a, b in zip(bounds, bounds[1:], strict=False) if b > a]


def _eval_jobs(plan: Plan, models: Path, params: Any,
               digests: dict[str, str]) -> list[EpisodeJob]:
    from simulator.experiment.training import learner_table

    jobs = []
    keys = [("dpa", "dpa")] if "dpa" in plan.controllers else []
    if "roger" in plan.controllers:
        keys += [("roger", f"roger:{k}") for k in range(plan.learner_seeds)]
    if "groups" in plan.controllers:  # served by the daemon like ROGER's own experts
        keys += [("roger", f"groups:{k}") for k in range(plan.learner_seeds)]
    if "hcc" in plan.controllers:
        keys.append(("hcc", "hcc"))
    # Longest first (learned controllers run longest), location chunks interleaved.
    for locs in location_chunks(plan.locations, EVAL_LOCATIONS_PER_JOB):
        for c, key in keys:
            k = int(key.split(":")[1]) if ":" in key else 0
            name = "-".join(f"{loc:02d}" for loc in (locs[0], locs[-1]))
            jobs.append(EpisodeJob(
                c, locs, plan.attempts, plan.seeds["eval_sim"], plan.time_limit, plan.vision,
                plan.out / "work" / "eval" / key.replace(":", "-") / f"loc-{name}",
                checkpoint_dir=models / key.replace(":", "-") if c != "hcc" else None,
                learner=learner_table(replace(params, particles=1) if key.startswith("groups")
                                      else params),
                learner_seed=plan.seeds["learner"] + k,
                task_config=plan.task_config, model_digest=digests.get(key, ""),
                name=key, rule=plan.rule,
            ))
    return jobs


def run(args: argparse.Namespace) -> int:
    """Run the experiment; 0 on success, 1 if a job or the daemon check failed, 2 on bad args."""
    from rich.console import Console

    try:
        plan = plan_from_args(args)
        params = learner_params(plan)
        starts = _load_starts(plan)
    except ValueError as exc:  # SimConfigError and StartPoseError are ValueErrors
        print(f"roger experiment goal-scoring: {exc}", file=sys.stderr)
        return 2
    if args.plan:
        print(json.dumps({**plan.to_json(), "learner": params.to_mapping()}, indent=1))
        return 0
    console = Console(stderr=False)
    from simulator.experiment.procs import stop_children_on_signals

    stop_children_on_signals()
    if plan.streams:
        from simulator.experiment.streams import run_streams

        return run_streams(plan, params, console, starts)
    return Experiment(plan, params, console, starts).run()



def _load_starts(plan: Plan) -> list[Any] | None:
    if plan.start_poses is None:
        return None
    from simulator.experiment.start_poses import load_start_poses

    return load_start_poses(plan.start_poses)


class Experiment:
    """The pipeline; every phase records its wall time in ``timings``."""

    def __init__(self, plan: Plan, params: Any, console: Any,
                 starts: list[Any] | None = None) -> None:
        self.plan = plan
        self.params = params
        self.console = console
        self.starts = starts
        self.context: dict[str, Any] = {}  # stream, models, unimap, oracle (for --start-poses)
        self.timings: dict[str, float] = {}
        self.errors: list[str] = []
        self.machine: dict[str, Any] | None = None  # the machine record, from the start

    def _phase(self, name: str, t0: float) -> None:
        self.timings[name] = round(time.monotonic() - t0, 2)

    def run(self) -> int:
        plan, console = self.plan, self.console
        plan.out.mkdir(parents=True, exist_ok=True)
        t_all = time.monotonic()
        self.machine = machine_record()
        console.rule("roger experiment goal-scoring")
        console.print(f"out {plan.out}  seed {plan.seed}  jobs {plan.jobs}  "
                      f"locations {list(plan.locations)}  shots {plan.shots}  attempts "
                      f"{plan.attempts}  learner seeds {plan.learner_seeds}  vision "
                      f"{plan.vision}  time limit {plan.time_limit:g} s  "
                      f"{'in-process' if plan.in_process else 'Zenoh'}"
                      + ("  [bold](quick)[/bold]" if plan.quick else ""))
        if plan.in_process:
            from simulator.experiment.pipeline import run_in_process

            results = run_in_process(plan, self.params, console, self.context)
        else:
            zenoh = self._zenoh()
            if zenoh is None:
                return 1
            results = zenoh
        if self.starts is not None:
            t0 = time.monotonic()
            results["held_out"] = self._held_out()
            self._phase("held_out", t0)
        results.setdefault("timings_s", {}).update(self.timings)
        results["timings_s"]["total"] = round(time.monotonic() - t_all, 2)
        return self._finish(results)

    def _held_out(self) -> dict[str, Any]:
        from simulator.experiment.start_poses import evaluate_held_out

        assert self.starts is not None
        return evaluate_held_out(self.plan, self.context, self.starts)

    def _finish(self, results: dict[str, Any]) -> int:
        from simulator.experiment.report import print_report

        plan, console = self.plan, self.console
        results["errors"] = list(results.get("errors", [])) + self.errors
        results["machine"] = machine(self.machine)
        path = plan.out / "results.json"
        write_json(path, results, default=json_default)
        print_report(console, results)
        console.print(f"results: {path}")
        for name, f in results.get("figures", {}).items():
            console.print(f"figure {name}: {f}")
        if results["errors"]:
            console.print(f"[red]{len(results['errors'])} error(s); see results.json 'errors'"
                          "[/red]")
            return 1
        return 0

    def _zenoh(self) -> dict[str, Any] | None:
        """The reference path: every episode through Zenoh processes (see the module)."""
        from simulator.experiment.zenoh_run import ZenohRun

        run = ZenohRun(self.plan, self.params, self.console, self.timings, self.context)
        results = run.run()
        self.errors += run.errors
        if results is None:
            self._write_failure()
        return results

    def _write_failure(self) -> None:
        path = self.plan.out / "results.json"
        write_json(path, {"schema": "roger.experiment.goal_scoring/1",
                          "seed": self.plan.seed, "errors": self.errors,
                          "plan": self.plan.to_json(), "timings_s": self.timings})

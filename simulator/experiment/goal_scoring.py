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
import platform
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.atomic import write_json
from simulator.experiment.procs import (
    EpisodeJob,
    JobError,
    JobResult,
    count_episodes,
    load_finished,
    run_job,
)

__all__ = ["CONTROLLERS", "PAPER", "Plan", "configure", "plan_from_args", "run"]

CONTROLLERS = ("hcc", "roger", "dpa")
CONTROLLER_NAMES = {
    "hcc": "HCC (hand-coded controller)",
    "roger": "ROGER experts + HCC transitioner",
    "dpa": "unimap GP (DPA)",
}
#: The paper's numbers (section IV.A): success rates, experts, ratio learned/HCC.
PAPER = {"hcc": 0.69, "roger": 0.31, "dpa": 0.0, "experts": 85, "ratio": 0.45}
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

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["out"] = str(self.out)
        d["locations"] = list(self.locations)
        d["controllers"] = list(self.controllers)
        d["overrides"] = list(self.overrides)
        return d


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment goal-scoring``."""
    parser.add_argument("--out", type=Path, required=True, help="output directory")
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
    parser.add_argument("--time-limit", type=float, default=None,
                        help="simulated seconds per episode (default 150, the paper's)")
    parser.add_argument("--vision", choices=("rendered", "fast"), default=None,
                        help="simulator vision (default rendered; --quick: fast)")
    parser.add_argument("--controllers", default=",".join(CONTROLLERS),
                        help="controllers to evaluate (default hcc,roger,dpa)")
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
    parser.add_argument("--plan", action="store_true", help="print the resolved plan and exit")


def plan_from_args(args: argparse.Namespace) -> Plan:
    """Resolve quick presets and defaults; raise ``ValueError`` on bad values."""
    from simulator.episodes import parse_locations

    quick = bool(args.quick)
    locations = parse_locations(args.locations or ("0,6" if quick else "all"))
    attempts = args.attempts if args.attempts is not None else (1 if quick else 3)
    per_subtask = args.per_subtask if args.per_subtask is not None else (150 if quick else 1000)
    time_limit = args.time_limit if args.time_limit is not None else (20.0 if quick else 150.0)
    vision = args.vision or ("fast" if quick else "rendered")
    controllers = tuple(c.strip() for c in args.controllers.split(",") if c.strip())
    bad = [c for c in controllers if c not in CONTROLLERS]
    if bad:
        raise ValueError(f"unknown controller(s) {bad}; choose from {list(CONTROLLERS)}")
    if attempts < 1 or per_subtask < 1 or time_limit <= 0:
        raise ValueError("--attempts and --per-subtask must be >= 1, --time-limit > 0")
    for o in args.overrides:
        if not o.startswith("learner."):
            raise ValueError(f"--set {o!r}: only learner.KEY=VALUE overrides are used here")
    jobs = args.jobs if args.jobs and args.jobs > 0 else (os.cpu_count() or 1)
    seed = int(args.seed)
    seeds = {
        "master": seed,
        "demo_sim": seed,
        "downsample": seed,
        "learner": seed,
        "eval_sim": seed + _EVAL_SEED_OFFSET,
    }
    return Plan(
        out=Path(args.out), seed=seed, jobs=jobs, quick=quick, locations=tuple(locations),
        attempts=attempts, per_subtask=per_subtask, time_limit=float(time_limit),
        vision=vision, daemon_check=bool(args.daemon_check), controllers=controllers,
        config=args.config, overrides=tuple(args.overrides), task_config=args.task_config,
        retries=max(0, int(args.retries)), resume=bool(args.resume), seeds=seeds,
    )


def learner_params(plan: Plan) -> Any:
    """The learner parameters: the paper's, then ``--config``'s [learner], then ``--set``."""
    from roger_daemon.config import load_config

    cfg = load_config(plan.config, list(plan.overrides))
    return cfg.robots[0].params


# --- running jobs with progress ---------------------------------------------------------


class _Runner:
    """Runs :class:`EpisodeJob` s on a thread pool (each job is its own processes)."""

    def __init__(self, plan: Plan, console: Any, progress: Any) -> None:
        self.plan = plan
        self.console = console
        self.progress = progress
        self.errors: list[str] = []
        self.reused = 0

    def run(self, jobs: Sequence[EpisodeJob], tasks: dict[str, Any],
            on_done: Callable[[JobResult], None] | None = None) -> list[JobResult | None]:
        """Run ``jobs``; progress per controller task; ``None`` for a job that failed."""
        results: list[JobResult | None] = [None] * len(jobs)
        shown: dict[int, int] = {}
        with ThreadPoolExecutor(max_workers=self.plan.jobs) as pool:
            futures: dict[Future[JobResult], int] = {
                pool.submit(self._attempt, job): i for i, job in enumerate(jobs)
            }
            pending = set(futures)
            while pending:
                done = {f for f in pending if f.done()}
                for f in done:
                    i = futures[f]
                    pending.discard(f)
                    job = jobs[i]
                    try:
                        res: JobResult | None = f.result()
                    except Exception as exc:
                        res = None
                        msg = f"{job.controller} locations {list(job.locations)}: {exc}"
                        self.errors.append(msg)
                        self.console.log(f"[red]job failed[/red] {msg[:2000]}")
                    results[i] = res
                    n = job.episodes
                    self.progress.advance(tasks[job.controller], n - shown.get(i, 0))
                    shown[i] = n
                    if res is not None:
                        self._log_done(res)
                        if on_done is not None:
                            on_done(res)
                for f in pending:
                    i = futures[f]
                    n = min(count_episodes(jobs[i].sim_log), jobs[i].episodes)
                    if n > shown.get(i, 0):
                        self.progress.advance(tasks[jobs[i].controller], n - shown.get(i, 0))
                        shown[i] = n
                time.sleep(0.3)
        return results

    def _attempt(self, job: EpisodeJob) -> JobResult:
        if self.plan.resume:
            earlier = load_finished(job)
            if earlier is not None:
                self.reused += 1
                return earlier
        last: Exception | None = None
        for k in range(self.plan.retries + 1):
            try:
                return run_job(job)
            except (JobError, OSError, ValueError, KeyError) as exc:
                last = exc
                if k < self.plan.retries:
                    self.console.log(f"[yellow]retrying[/yellow] {job.controller} locations "
                                     f"{list(job.locations)} after: {str(exc)[:300]}")
        assert last is not None
        raise last

    def _log_done(self, res: JobResult) -> None:
        outs = ", ".join(e["outcome"] for e in res.episodes)
        locs = ",".join(str(loc) for loc in res.job.locations)
        self.console.log(f"{res.job.controller:>5} location {locs}: {outs} "
                         f"({res.wall_s:.0f} s, {res.summary.get('ticks_per_s', 0)} ticks/s)")


def _progress(console: Any) -> Any:
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(TextColumn("{task.description:<34}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TimeRemainingColumn(), console=console)


# --- the phases -------------------------------------------------------------------------


def _demo_jobs(plan: Plan) -> list[EpisodeJob]:
    return [
        EpisodeJob("demo", (loc,), 1, plan.seeds["demo_sim"], plan.time_limit, plan.vision,
                   plan.out / "work" / "demo" / f"loc-{loc:02d}",
                   task_config=plan.task_config)
        for loc in plan.locations
    ]


def _eval_jobs(plan: Plan, models: Path, params: Any,
               digests: dict[str, str]) -> list[EpisodeJob]:
    from simulator.experiment.training import learner_table

    jobs = []
    # Longest first (learned controllers mostly run to the time limit), locations interleaved.
    order = [c for c in ("dpa", "roger", "hcc") if c in plan.controllers]
    for loc in plan.locations:
        for c in order:
            jobs.append(EpisodeJob(
                c, (loc,), plan.attempts, plan.seeds["eval_sim"], plan.time_limit, plan.vision,
                plan.out / "work" / "eval" / c / f"loc-{loc:02d}",
                checkpoint_dir=models / c if c in ("roger", "dpa") else None,
                learner=learner_table(params), learner_seed=plan.seeds["learner"],
                task_config=plan.task_config, model_digest=digests.get(c, ""),
            ))
    return jobs


def _controller_stats(results: Sequence[JobResult | None]) -> dict[str, int]:
    """Sum of the numeric counters of the simulators and controllers (transport health)."""
    keys_sim = ("command_timeouts", "hold_ticks", "stale_commands", "future_commands",
                "resends", "invalid_messages", "ticks")
    keys_ctl = ("label", "fallback_top", "fallback_mean", "no_prediction", "resent",
                "repeated_ticks", "invalid_messages")
    out: Counter[str] = Counter()
    for r in results:
        if r is None:
            continue
        for k in keys_sim:
            out[f"sim_{k}"] += int(r.summary.get(k, 0))
        for k in keys_ctl:
            if k in r.controller_stats:
                out[f"controller_{k}"] += int(r.controller_stats[k])
        for label, n in (r.controller_stats.get("subtask_ticks") or {}).items():
            out[f"subtask_ticks_{label}"] += int(n)
    return dict(sorted(out.items()))


def run(args: argparse.Namespace) -> int:
    """Run the experiment; 0 on success, 1 if a job or the daemon check failed, 2 on bad args."""
    from rich.console import Console

    try:
        plan = plan_from_args(args)
        params = learner_params(plan)
    except ValueError as exc:  # ConfigError is a ValueError
        print(f"roger experiment goal-scoring: {exc}", file=sys.stderr)
        return 2
    if args.plan:
        print(json.dumps({**plan.to_json(), "learner": params.to_mapping()}, indent=1))
        return 0
    console = Console(stderr=False)
    return Experiment(plan, params, console).run()


class Experiment:
    """The pipeline; every phase records its wall time in ``timings``."""

    def __init__(self, plan: Plan, params: Any, console: Any) -> None:
        self.plan = plan
        self.params = params
        self.console = console
        self.timings: dict[str, float] = {}
        self.errors: list[str] = []

    def _phase(self, name: str, t0: float) -> None:
        self.timings[name] = round(time.monotonic() - t0, 2)

    def run(self) -> int:
        from roger_daemon.labels import majority_labels
        from roger_daemon.learner import Roger, UnimapGP
        from simulator.experiment.metrics import downsample_per_label
        from simulator.experiment.training import (
            daemon_check,
            load_demonstrations,
            train,
            write_model_checkpoint,
        )

        plan, params, console = self.plan, self.params, self.console
        plan.out.mkdir(parents=True, exist_ok=True)
        t_all = time.monotonic()
        console.rule("roger experiment goal-scoring")
        console.print(f"out {plan.out}  seed {plan.seed}  jobs {plan.jobs}  "
                      f"locations {list(plan.locations)}  attempts {plan.attempts}  "
                      f"vision {plan.vision}  time limit {plan.time_limit:g} s"
                      + ("  [bold](quick)[/bold]" if plan.quick else ""))
        n_demo = len(plan.locations)
        n_eval = len(plan.locations) * plan.attempts
        with _progress(console) as progress:
            runner = _Runner(plan, console, progress)
            # 1. demonstrations
            t0 = time.monotonic()
            demo_task = progress.add_task("1 demonstrations (HCC, recorded)", total=n_demo)
            train_task = progress.add_task("3 training ROGER (offline)", total=None,
                                           start=False)
            check_task = (progress.add_task("3 same stream through the daemon", total=None,
                                            start=False) if plan.daemon_check else None)
            eval_tasks = {c: progress.add_task(f"5 evaluation: {c}", total=n_eval, start=False)
                          for c in plan.controllers}
            demos = runner.run(_demo_jobs(plan), {"demo": demo_task})
            self._phase("demonstrations", t0)
            if any(r is None for r in demos):
                self.errors += runner.errors
                console.print("[red]demonstrations failed; stopping[/red]")
                self._write_failure()
                return 1
            demo_results = [r for r in demos if r is not None]
            # 2. downsample
            t0 = time.monotonic()
            data = load_demonstrations([(r.job.locations[0], r.mcap) for r in demo_results])
            rng = np.random.default_rng(plan.seeds["downsample"])
            idx = downsample_per_label(data.labels, plan.per_subtask, rng)
            stream = data.subset(idx)
            self._phase("downsample", t0)
            # 3. train
            t0 = time.monotonic()
            progress.update(train_task, total=len(stream))
            progress.start_task(train_task)
            model = Roger(d_x=stream.x.shape[1], d_y=stream.y.shape[1], params=params,
                          seed=plan.seeds["learner"])
            train_s = train(model, stream.x, stream.y,
                            progress=lambda n: progress.advance(train_task, n))
            unimap = UnimapGP(d_x=stream.x.shape[1], d_y=stream.y.shape[1], params=params,
                              seed=plan.seeds["learner"])
            unimap_s = train(unimap, stream.x, stream.y)
            self._phase("training", t0)
            console.log(f"ROGER learned {len(stream)} pairs in {train_s:.1f} s: "
                        f"{model.n_experts} experts; unimap GP in {unimap_s:.1f} s")
            check: dict[str, Any] | None = None
            if check_task is not None:
                t0 = time.monotonic()
                progress.update(check_task, total=len(stream))
                progress.start_task(check_task)
                try:
                    check = daemon_check(
                        stream.x, stream.y, stream.labels, model, params=params,
                        seed=plan.seeds["learner"], workdir=plan.out / "work" / "daemon-check",
                        progress=lambda n: progress.advance(check_task, n))
                except Exception as exc:  # reported, and the run exits 1
                    check = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
                self._phase("daemon_check", t0)
                style = "green" if check.get("ok") else "red"
                console.log(f"[{style}]daemon check: {'identical' if check.get('ok') else 'FAILED'}"
                            f"[/{style}] (offline = daemon = replay of its log)")
                if not check.get("ok"):
                    self.errors.append(f"daemon check failed: {json.dumps(check)[:2000]}")
            # 4. group experts and write the checkpoints the daemons resume from
            t0 = time.monotonic()
            assignments = np.asarray(model.assignments())
            groups = majority_labels(assignments.tolist(), stream.labels)
            models = plan.out / "models"
            for sub in ("roger", "dpa"):
                d = models / sub / "aibo"
                if d.is_dir():
                    for f in d.glob("ckpt-*.npz"):
                        f.unlink()
            digests = {}
            for sub, m, kind in (("roger", model, "roger"), ("dpa", unimap, "unimap")):
                _, meta = write_model_checkpoint(models / sub, m, stream.labels, model_kind=kind,
                                                 seed=plan.seeds["learner"], params=params)
                digests[sub] = str(meta["model_digest"])
            np.savez_compressed(
                plan.out / "training-data.npz", x=stream.x, y=stream.y,
                labels=np.array(stream.labels, dtype=np.str_), location=stream.location,
                tick=stream.tick, assignments=assignments,
            )
            self._phase("grouping", t0)
            # 5. evaluate
            t0 = time.monotonic()
            for task in eval_tasks.values():
                progress.start_task(task)
            ev = runner.run(_eval_jobs(plan, models, params, digests), eval_tasks)
            self._phase("evaluation", t0)
            self.errors += runner.errors
        # 6. + 7. report and figures
        t0 = time.monotonic()
        from simulator.experiment.report import build_results, print_report, write_figures

        results = build_results(
            plan=plan, params=params, demos=demo_results, data=data, stream=stream,
            model=model, groups=groups, evals=[r for r in ev if r is not None],
            check=check, train_s=train_s, errors=self.errors,
        )
        results["figures"] = write_figures(plan.out, stream, assignments, results)
        results["models"] = {
            sub: {"checkpoint_dir": str(models / sub), "model_digest": digests[sub]}
            for sub in ("roger", "dpa")
        }
        self._phase("report", t0)
        self.timings["total"] = round(time.monotonic() - t_all, 2)
        results["timings_s"] = dict(self.timings)
        results["transport"] = {
            "demo": _controller_stats(demo_results),
            **{c: _controller_stats([r for r in ev if r is not None and r.job.controller == c])
               for c in plan.controllers},
        }
        # process time of the jobs (kept from the original run when --resume reused them)
        results["resumed_jobs"] = runner.reused
        results["jobs_wall_s"] = {
            "demo": round(sum(r.wall_s for r in demo_results), 1),
            **{c: round(sum(r.wall_s for r in ev if r is not None and r.job.controller == c), 1)
               for c in plan.controllers},
        }
        results["machine"] = _machine()
        path = plan.out / "results.json"
        write_json(path, results, default=_json_default)
        print_report(console, results)
        console.print(f"results: {path}")
        for name, f in results["figures"].items():
            console.print(f"figure {name}: {f}")
        if self.errors:
            console.print(f"[red]{len(self.errors)} error(s); see results.json 'errors'[/red]")
            return 1
        return 0

    def _write_failure(self) -> None:
        path = self.plan.out / "results.json"
        write_json(path, {"schema": "roger.experiment.goal_scoring/1",
                          "seed": self.plan.seed, "errors": self.errors,
                          "plan": self.plan.to_json(), "timings_s": self.timings})


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _machine() -> dict[str, Any]:
    from importlib.metadata import PackageNotFoundError, version

    from roger_daemon.blas import blas_info

    versions: dict[str, str | None] = {}
    for pkg in ("numpy", "scipy", "pybullet", "eclipse-zenoh", "scikit-learn", "mcap"):
        try:
            versions[pkg] = version(pkg)
        except PackageNotFoundError:
            versions[pkg] = None
    return {
        "cpus": os.cpu_count(),
        "loadavg_1m_end": round(os.getloadavg()[0], 2),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "versions": versions,
        "blas": blas_info(),
    }

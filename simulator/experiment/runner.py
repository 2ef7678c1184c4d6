"""Job running for ``roger experiment goal-scoring``: a thread pool of process jobs with
progress bars, transport counters, the machine record and JSON encoding of numpy values."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from simulator.experiment.jobs import EpisodeJob, JobResult, load_finished, run_job
from simulator.experiment.procs import CHILDREN, JobError, count_episodes

__all__ = ["Runner", "controller_stats", "json_default", "machine", "progress_bars"]


def controller_stats(results: Sequence[JobResult | None]) -> dict[str, int]:
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


class Runner:
    """Runs :class:`EpisodeJob` s on a thread pool (each job is its own processes)."""

    def __init__(self, plan: Any, console: Any, progress: Any) -> None:
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
                    self.progress.advance(tasks[job.key], n - shown.get(i, 0))
                    shown[i] = n
                    if res is not None:
                        self._log_done(res)
                        if on_done is not None:
                            on_done(res)
                for f in pending:
                    i = futures[f]
                    n = min(count_episodes(jobs[i].sim_log), jobs[i].episodes)
                    if n > shown.get(i, 0):
                        self.progress.advance(tasks[jobs[i].key], n - shown.get(i, 0))
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
                if k < self.plan.retries and not CHILDREN.stopping:
                    self.console.log(f"[yellow]retrying[/yellow] {job.controller} locations "
                                     f"{list(job.locations)} after: {str(exc)[:300]}")
        assert last is not None
        raise last

    def _log_done(self, res: JobResult) -> None:
        outs = ", ".join(e["outcome"] for e in res.episodes)
        locs = ",".join(str(loc) for loc in res.job.locations)
        self.console.log(f"{res.job.controller:>5} location {locs}: {outs} "
                         f"({res.wall_s:.0f} s, {res.summary.get('ticks_per_s', 0)} ticks/s)")


def progress_bars(console: Any) -> Any:
    """Rich progress bars for the phases of a run."""
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



def json_default(o: Any) -> Any:
    """JSON encoder fallback for numpy scalars, arrays and paths."""
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def machine(start: dict[str, Any] | None = None) -> dict[str, Any]:
    """The machine record of this run (:mod:`roger_daemon.machine`, taken at its ``start``;
    now if ``None``), finished now, with the package versions (for results.json)."""
    from importlib.metadata import PackageNotFoundError, version

    from roger_daemon.machine import finish, machine_record

    versions: dict[str, str | None] = {}
    for pkg in ("numpy", "scipy", "pybullet", "eclipse-zenoh", "scikit-learn", "mcap"):
        try:
            versions[pkg] = version(pkg)
        except PackageNotFoundError:
            versions[pkg] = None
    record = finish(dict(start) if start is not None else machine_record())
    record["versions"] = versions
    return record

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
(``--jobs``). ``--quick`` is a small version of the same pipeline for CI. The arguments and
their resolution into a :class:`~simulator.experiment.goal_plan.Plan` are in
:mod:`simulator.experiment.goal_plan`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from roger_daemon.atomic import write_json
from roger_daemon.machine import machine_record
from simulator.experiment.goal_plan import Plan, configure, plan_from_args
from simulator.experiment.jobs import EpisodeJob
from simulator.experiment.runner import json_default, machine

__all__ = ["PAPER", "configure", "run"]

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
#: Start locations per evaluation job (one simulator, controller and daemon run them all):
#: each job's processes cost a few seconds to start and stop, so fewer, longer jobs; an
#: episode does not depend on the job it runs in (``paths_agree`` compares episode by episode).
EVAL_LOCATIONS_PER_JOB = 5


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
                   task_config=plan.task_config, demo_noise=plan.demo_noise)
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


def _one_particle(plan: Plan, key: str) -> bool:
    """Whether the checkpoint of ``key`` is a one-particle model: merged groups, and ROGER's
    split gates (``--gates split``, :func:`roger_daemon.gate_split_model.split_model`)."""
    return key.startswith("groups") or (key.startswith("roger") and plan.gates == "split")


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
                learner=learner_table(replace(params, particles=1) if _one_particle(plan, key)
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

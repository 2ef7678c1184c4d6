"""The reference path of ``roger experiment goal-scoring``: every episode through Zenoh.

Demonstrations (``roger sim`` + ``roger hcc`` + ``roger record``, one job per location, one
MCAP per job), training (:mod:`simulator.experiment.pipeline`), the daemon check of the first
model (:func:`simulator.experiment.training.daemon_check`), checkpoints, and evaluation jobs
(``hcc``; ``roger:K`` = daemon resumed from learner seed K's model + ``roger hcc --role
transitioner``; ``groups:K`` = the same with model K's experts merged per group; ``dpa``). The
segmentation oracle has no daemon model kind, so it is evaluated
in this process (the same code as ``--in-process``) while the Zenoh jobs run; a shared subset
is re-run in-process and compared episode by episode (``results["paths_agree"]``).
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import replace
from typing import Any

import numpy as np

from simulator.experiment.jobs import JobResult
from simulator.experiment.runner import Runner, controller_stats, progress_bars

__all__ = ["ZenohRun", "add_averaging", "compare_paths"]


def compare_paths(zenoh: dict[str, list[dict[str, Any]]],
                  local: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """Episode-by-episode comparison (outcome, ticks, motion counters) of the two paths."""
    rows = []
    for key, eps in sorted(local.items()):
        theirs = {(e["location"], e["repetition"]): e for e in zenoh.get(key, [])}
        for e in eps:
            z = theirs.get((e["location"], e["repetition"]))
            same = z is not None and all(
                z.get(f) == e.get(f) for f in ("outcome", "ticks", "traps", "kicks"))
            rows.append({"controller": key, "location": e["location"],
                         "repetition": e["repetition"], "in_process": e["outcome"],
                         "in_process_ticks": e["ticks"],
                         "zenoh": None if z is None else z["outcome"],
                         "zenoh_ticks": None if z is None else z["ticks"], "same": same})
    return {"episodes": rows, "all_same": bool(rows) and all(r["same"] for r in rows)}


def add_averaging(jobs: list[JobResult], stream: Any) -> None:
    """Each DPA episode's ``aliased_share``/``averaged_share`` from its job's trace
    (:mod:`simulator.experiment.averaging`); a job whose trace is missing or does not hold
    its episodes gets none."""
    from simulator.experiment.averaging import MultimapNeighbourhood
    from simulator.experiment.dpa_node import read_trace
    from simulator.experiment.jobs import DPA_TRACE

    hood = MultimapNeighbourhood(stream.x, stream.y)
    for r in jobs:
        path = r.job.workdir / DPA_TRACE
        traced = read_trace(path) if path.is_file() else []
        if len(traced) != len(r.episodes):
            continue
        for ep, (x, y) in zip(r.episodes, traced, strict=True):
            if len(x):
                ep.update(hood.episode_summary(x, y))


class ZenohRun:
    """One run of the Zenoh pipeline; :meth:`run` returns ``results`` or ``None`` on failure."""

    def __init__(self, plan: Any, params: Any, console: Any, timings: dict[str, float],
                 context: dict[str, Any]) -> None:
        self.context = context
        self.plan = plan
        self.params = params
        self.console = console
        self.timings = timings
        self.errors: list[str] = []
        self.reused = 0

    def _phase(self, name: str, t0: float) -> None:
        self.timings[name] = round(time.monotonic() - t0, 2)

    def run(self) -> dict[str, Any] | None:
        """Run every phase over Zenoh; the results, or None if a phase failed."""
        from simulator.experiment.goal_scoring import _demo_jobs
        from simulator.experiment.pipeline import downsample, merge_all, train_models
        from simulator.experiment.training import load_demonstrations

        plan = self.plan
        with progress_bars(self.console) as progress:
            runner = Runner(plan, self.console, progress)
            t0 = time.monotonic()
            demo_task = progress.add_task("1 demonstrations (HCC, recorded)",
                                          total=len(plan.locations) * plan.shots)
            demos = runner.run(_demo_jobs(plan), {"demo": demo_task})
            self._phase("demonstrations", t0)
            if any(r is None for r in demos):
                self.errors += runner.errors
                self.console.print("[red]demonstrations failed; stopping[/red]")
                return None
            demo_results = [r for r in demos if r is not None]
            data = load_demonstrations([(r.job.locations[0], r.mcap) for r in demo_results])
            stream = downsample(data, plan)
            t0 = time.monotonic()
            task = progress.add_task("3 training ROGER (offline)",
                                     total=len(stream) * plan.learner_seeds)
            models, unimap, train_s = train_models(
                stream, self.params, plan, progress=lambda n: progress.advance(task, n))
            self._phase("training", t0)
            self.console.log(f"ROGER learned {len(stream)} pairs in {train_s:.1f} s: "
                             + ", ".join(f"seed {s}: {m.n_experts} experts"
                                         for s, m in models))
            merged = merge_all(stream, models, self.params, plan)
            self.context.update(stream=stream, models=models, unimap=unimap, merged=merged)
            # the daemon check feeds a daemon process in lockstep (mostly waiting on it): it
            # runs beside the checkpoints and the evaluation instead of before them
            checked: dict[str, Any] = {}
            checker = threading.Thread(
                target=lambda: checked.update(check=self._check(stream, models[0][1],
                                                                 progress)),
                name="daemon-check", daemon=True)
            checker.start()
            digests = self._checkpoints(stream, models, unimap, merged)
            ev, local_eps = self._evaluate(runner, progress, stream, models, unimap, digests)
            checker.join()
            check = checked.get("check")
            self.reused = runner.reused
        return self._results(demo_results, data, stream, models, merged, unimap, ev, local_eps,
                             check, train_s)

    def _check(self, stream: Any, model: Any, progress: Any) -> dict[str, Any] | None:
        from simulator.experiment.training import daemon_check

        plan = self.plan
        if not plan.daemon_check:
            return None
        t0 = time.monotonic()
        task = progress.add_task("3 same stream through the daemon", total=len(stream))
        try:
            check = daemon_check(
                stream.x, stream.y, stream.labels, model, params=self.params,
                seed=plan.seeds["learner"], workdir=plan.out / "work" / "daemon-check",
                progress=lambda n: progress.advance(task, n))
        except Exception as exc:  # reported, and the run exits 1
            check = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        self._phase("daemon_check", t0)
        style = "green" if check.get("ok") else "red"
        self.console.log(f"[{style}]daemon check: "
                         f"{'identical' if check.get('ok') else 'FAILED'}[/{style}] "
                         "(offline = daemon = replay of its log)")
        if not check.get("ok"):
            self.errors.append(f"daemon check failed: {json.dumps(check)[:2000]}")
        return check

    def _checkpoints(self, stream: Any, models: list[tuple[int, Any]], unimap: Any,
                     merged: list[Any]) -> dict[str, str]:
        """Write every model as a daemon checkpoint (models/roger-K, models/groups-K,
        models/dpa); a merged model's points carry their group's name, so that the daemon
        names each merged expert by its group. With ``--gates split`` models/roger-K holds
        the split gates as a one-particle ROGER model
        (:func:`roger_daemon.gate_split_model.split_model`: the in-process row's multimap,
        float for float)."""
        from roger_daemon.gate_split import SplitGates
        from roger_daemon.gate_split_model import split_model
        from simulator.experiment.pipeline import gated, save_training_data
        from simulator.experiment.training import write_model_checkpoint

        plan = self.plan
        t0 = time.monotonic()
        root = plan.out / "models"
        served = [(s, split_model(m) if isinstance(m, SplitGates) else m)
                  for s, m in gated(plan, stream, models)]
        todo = [(f"roger:{k}", m, "roger", s, stream.labels) for k, (s, m) in enumerate(served)]
        todo += [(f"groups:{k}", g.model, "roger", g.seed, g.group_of_point)
                 for k, g in enumerate(merged)]
        todo.append(("dpa", unimap, "unimap", plan.seeds["learner"], stream.labels))
        digests = {}
        for key, model, kind, seed, labels in todo:
            d = root / key.replace(":", "-")
            for f in (d / "aibo").glob("ckpt-*.npz") if (d / "aibo").is_dir() else []:
                f.unlink()
            _, meta = write_model_checkpoint(d, model, labels, model_kind=kind,
                                             seed=seed, params=model.params)
            digests[key] = meta.model_digest
        save_training_data(plan.out, stream, models[0][1])
        self._phase("grouping", t0)
        return digests

    def _evaluate(self, runner: Runner, progress: Any, stream: Any,
                  models: list[tuple[int, Any]], unimap: Any, digests: dict[str, str]
                  ) -> tuple[list[JobResult], dict[str, list[dict[str, Any]]]]:
        """Zenoh jobs on the pool; the segmentation oracle (no daemon model kind) in a thread
        meanwhile, in-process."""
        from simulator.experiment.goal_scoring import _eval_jobs
        from simulator.experiment.pipeline import (
            controllers_for,
            evaluate_in_process,
            fit_segmentation_oracle,
        )

        plan = self.plan
        t0 = time.monotonic()
        jobs = _eval_jobs(plan, plan.out / "models", self.params, digests)
        n = len(plan.locations) * plan.attempts
        tasks = {k: progress.add_task(f"5 evaluation: {k}", total=n)
                 for k in dict.fromkeys(j.key for j in jobs)}
        local_eps: dict[str, list[dict[str, Any]]] = {}
        thread = None
        if "oracle" in plan.controllers:
            o_task = progress.add_task("5 evaluation: oracle (in-process)", total=n)

            def oracle() -> None:
                gps = fit_segmentation_oracle(stream, self.params, plan.seeds["learner"])
                self.context["oracle"] = gps
                ctl = controllers_for(replace(plan, controllers=("oracle",)), stream, [],
                                      None, gps)
                local_eps.update(evaluate_in_process(
                    plan, ctl, on_episode=lambda k, r: progress.advance(o_task, 1)))

            thread = threading.Thread(target=oracle, name="oracle", daemon=True)
            thread.start()
        ev = runner.run(jobs, tasks)
        if thread is not None:
            thread.join()
        self._phase("evaluation", t0)
        self.errors += runner.errors
        return [r for r in ev if r is not None], local_eps

    def _results(self, demo_results: list[JobResult], data: Any, stream: Any,
                 models: list[tuple[int, Any]], merged: list[Any], unimap: Any,
                 ev: list[JobResult],
                 local_eps: dict[str, list[dict[str, Any]]], check: dict[str, Any] | None,
                 train_s: float) -> dict[str, Any]:
        from simulator.experiment.report import build_results, write_figures

        plan = self.plan
        t0 = time.monotonic()
        episodes: dict[str, list[dict[str, Any]]] = {}
        for r in ev:
            episodes.setdefault(r.job.key, []).extend(r.episodes)
        add_averaging([r for r in ev if r.job.key == "dpa"], stream)
        episodes.update(local_eps)
        results = build_results(
            plan=plan, params=self.params, demos=[e for r in demo_results for e in r.episodes],
            data=data, stream=stream, models=models, episodes=episodes, check=check,
            train_s=train_s, errors=[], mcap=[str(p) for r in demo_results for p in r.mcap])
        results["paths_agree"] = self._shared_subset(stream, models, merged, unimap, episodes)
        if not results["paths_agree"]["all_same"]:
            self.errors.append("in-process and Zenoh episodes differ on the shared subset")
        assignments = np.asarray(models[0][1].assignments())
        results["figures"] = write_figures(plan.out, stream, assignments, results)
        results["models"] = {str(p.name): str(p) for p in sorted((plan.out / "models").iterdir())}
        results["transport"] = {
            "demo": controller_stats(demo_results),
            **{k: controller_stats([r for r in ev if r.job.key == k]) for k in episodes
               if k not in local_eps},
        }
        results["resumed_jobs"] = self.reused
        # fsum: exact, so the order jobs finished in (or were reused in) cannot flip a rounding
        results["jobs_wall_s"] = {
            "demo": round(math.fsum(r.wall_s for r in demo_results), 1),
            **{k: round(math.fsum(r.wall_s for r in ev if r.job.key == k), 1) for k in episodes
               if k not in local_eps},
        }
        self._phase("report", t0)
        return results

    def _shared_subset(self, stream: Any, models: list[tuple[int, Any]], merged: list[Any],
                       unimap: Any, episodes: dict[str, list[dict[str, Any]]]
                       ) -> dict[str, Any]:
        """Re-run the first location's first attempt in-process; compare with Zenoh."""
        from simulator.experiment.pipeline import controllers_for, evaluate_in_process

        plan = self.plan
        # the rows both paths run (the learned transitions are fitted in-process only)
        sub = replace(plan, attempts=1, controllers=tuple(
            c for c in plan.controllers if c in ("hcc", "roger", "groups", "dpa")))
        ctl = {k: c for k, c in controllers_for(sub, stream, models[:1], unimap, None,
                                                 merged[:1]).items()
               if k in ("hcc", "roger:0", "groups:0", "dpa")}
        local = evaluate_in_process(sub, ctl, locations=plan.locations[:1])
        return compare_paths(episodes, local)

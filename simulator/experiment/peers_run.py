"""The phases of ``roger experiment peers`` (:mod:`simulator.experiment.peers` says what each
does); :class:`PeersRun` keeps what they share and the wall time of each."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.atomic import write_json
from simulator.experiment.peers import now, percentiles_ms

__all__ = ["PeersRun"]


class PeersRun:
    """One run: demonstrations, export, training, evaluation, curve, report."""

    def __init__(self, plan: Any, policies: list[str], steps: dict[str, int],
                 args: argparse.Namespace, curve: list[int], poses_file: str | None,
                 starts: list[Any] | None) -> None:
        from rich.console import Console

        self.plan = plan
        self.policies = policies
        self.steps = steps
        self.batch_size = int(args.batch_size)
        self.frames = str(args.frames)
        self.threads = int(args.threads)
        self.curve_attempts = int(args.curve_attempts)
        self.curve = curve
        self.poses_file = poses_file
        self.starts = starts
        self.console = Console()
        self.timings: dict[str, float] = {}
        self.out: Path = plan.out
        self.done: dict[str, Any] = {}

    def _log(self, text: str) -> None:
        self.console.log(text)

    def run(self) -> int:
        """Every phase; writes ``OUT/results.json`` after each (``complete`` false until the
        end, so that a stopped run keeps what it measured); 0 on success."""
        import torch

        from simulator.experiment import peers_data as pd
        from simulator.experiment.peers_report import write_curve_figure

        t_all = t0 = now()
        self.out.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(self.threads)
        data, records, kept = pd.demonstrations(self.plan)
        self.timings["demonstrations"] = round(now() - t0, 2)
        self._log(f"{len(records)} demonstrations, {len(data)} ticks, {kept.size} kept by the "
                  "downsampling")
        t0 = now()
        root = self.out / "dataset"
        pd.export_stream(data, root)
        self.timings["export"] = round(now() - t0, 2)
        starts = kept if self.frames == "downsampled" else None
        self.done = {"records": records, "data": data, "kept": kept, "peers": {}, "curve": {}}
        self.done["hcc"] = self._evaluate("hcc", None)
        for name in self.policies:
            self.done["peers"][name] = self._train_and_evaluate(name, root, starts)
            self._save()
        if self.curve:
            self._curve(data, records, kept, root, starts, self.done["peers"])
        figures = ({"learning_curve": str(write_curve_figure(self.out, self.done["curve"]))}
                   if self.curve else {})
        self.timings["total"] = round(now() - t_all, 2)
        results = self._save(complete=True, figures=figures)
        self._print(results)
        return 0

    def _save(self, complete: bool = False, figures: dict[str, str] | None = None
              ) -> dict[str, Any]:
        from simulator.experiment.peers_report import build_results

        d = self.done
        results = build_results(self, d["records"], d["data"], d["kept"], d["hcc"], d["peers"],
                                d["curve"])
        results.update(complete=complete, figures=figures or {}, timings_s=self.timings)
        write_json(self.out / "results.json", results)
        return results

    # --- evaluation ---------------------------------------------------------------------

    def _evaluate(self, key: str, controller: Any, attempts: int | None = None,
                  held_out: bool = True) -> dict[str, list[dict[str, Any]]]:
        """Episodes of one controller from the start locations (and the held-out poses)."""
        from dataclasses import replace

        from simulator.experiment.pipeline import evaluate_in_process, make_hcc

        t0 = now()
        plan = self.plan if attempts is None else replace(self.plan, attempts=attempts)
        ctl = make_hcc(plan) if controller is None else controller
        out = {"locations": evaluate_in_process(plan, {key: ctl})[key]}
        if held_out and self.starts is not None:
            out["held_out"] = evaluate_in_process(plan, {key: ctl},
                                                  locations=list(range(len(self.starts))),
                                                  starts=self.starts)[key]
        self.timings[f"evaluate:{key}"] = round(now() - t0, 2)
        wins = sum(bool(e["success"]) for e in out["locations"])
        self._log(f"{key}: {wins}/{len(out['locations'])} goals from the start locations")
        return out

    def _train(self, name: str, root: Path, starts: Any, episodes: list[int] | None,
               tag: str) -> Any:
        import torch

        from simulator.experiment.peers_policy import train_policy

        torch.set_num_threads(self.threads)
        t0 = now()
        trained = train_policy(
            name, root, steps=self.steps[name], batch_size=self.batch_size,
            seed=self.plan.seed, episodes=episodes, starts=starts,
            progress=lambda s, loss: self._log(f"{tag} step {s}: loss {loss:.4f}")
            if s % 500 == 0 or s == self.steps[name] else None)
        self.timings[f"train:{tag}"] = round(now() - t0, 2)
        self._log(f"{tag}: {trained.steps} steps, {trained.train_cpu_s:.0f} CPU s, "
                  f"{trained.parameters():,} parameters")
        return trained

    def _controller(self, trained: Any) -> Any:
        import torch

        from simulator.experiment.peers_policy import PolicyController

        torch.set_num_threads(1)  # inference time per tick on one core
        return PolicyController(trained, seed=self.plan.seeds["eval_sim"])

    def _train_and_evaluate(self, name: str, root: Path, starts: Any) -> dict[str, Any]:
        trained = self._train(name, root, starts, None, name)
        size = trained.save(self.out / "models" / name)
        ctl = self._controller(trained)
        episodes = self._evaluate(name, ctl)
        return {"trained": trained, "episodes": episodes, "model_bytes": size,
                         **percentiles_ms(ctl.times_s), "ticks_timed": len(ctl.times_s),
                         "non_finite": ctl.counts.get("non_finite", 0)}

    # --- learning curve -------------------------------------------------------------------

    def _curve(self, data: Any, records: list[dict[str, Any]], kept: Any, root: Path,
               starts: Any, peers: dict[str, Any]) -> None:
        """Fills ``self.done["curve"]`` point by point (saved after each)."""
        from simulator.experiment import peers_data as pd

        total = len(records)
        out = self.done["curve"]
        out.update({"demonstrations": self.curve, "attempts": self.curve_attempts,
                    "order": "round-robin over the start locations"})
        self._roger_curve(data, records, kept, out)
        for name in self.policies:
            rows = out.setdefault(name, [])
            for n in self.curve:
                if n == total:  # the main run's model: its first attempt per location
                    eps = [e for e in peers[name]["episodes"]["locations"]
                           if e["repetition"] < self.curve_attempts]
                    cpu = peers[name]["trained"].train_cpu_s
                else:
                    trained = self._train(name, root, starts, pd.curve_episodes(records, n),
                                          f"{name}@{n}")
                    eps = self._evaluate(f"{name}@{n}", self._controller(trained),
                                         self.curve_attempts, held_out=False)["locations"]
                    cpu = trained.train_cpu_s
                rows.append(_point(n, eps, train_cpu_s=cpu))
                self._save()

    def _roger_curve(self, data: Any, records: list[dict[str, Any]], kept: Any,
                     out: dict[str, Any]) -> None:
        """ROGER learning the kept points in the curve's order, one pass, evaluated after
        each point with the HCC transitioner (``roger``) and alone (``autonomous``)."""
        import time as _time

        from roger_daemon.learner import Roger, load_model
        from simulator.experiment import peers_data as pd
        from simulator.experiment.goal_scoring import learner_params
        from simulator.experiment.pipeline import controllers_for, fit_transitions

        params = learner_params(self.plan)
        stream, rank = pd.curve_stream(data, kept, records)
        model = Roger(d_x=stream.x.shape[1], d_y=stream.y.shape[1], params=params,
                      seed=self.plan.seeds["learner"])
        episode = pd.episode_of(data)
        rows: dict[str, list[dict[str, Any]]] = {"roger": [], "autonomous": []}
        out.update(rows)
        done, cpu = 0, 0.0
        for n in self.curve:
            c0 = _time.process_time()
            upto = int(np.searchsorted(rank, n, side="left"))
            for i in range(done, upto):
                model.learn_one(stream.x[i], stream.y[i])
            cpu += _time.process_time() - c0
            done = upto
            snap = load_model(model.state_dict())
            # the whole stream of those demonstrations, in the curve's order (docs/autonomy.md)
            order = np.concatenate([np.flatnonzero(episode == d)
                                    for d in pd.curve_order(records)[:n]])
            sub = stream.subset(np.arange(upto))
            fsms = fit_transitions(data.subset(order), [(0, snap)], self.plan, sub)
            ctl = controllers_for(self.plan, sub, [(0, snap)], None, None, (), fsms)
            for key in ("roger", "autonomous"):
                eps = self._evaluate(f"{key}@{n}", ctl[f"{key}:0"], self.curve_attempts,
                                     held_out=False)["locations"]
                rows[key].append(_point(n, eps, train_cpu_s=round(cpu, 2), pairs=upto,
                                        experts=int(snap.n_experts)))
            self._save()

    def _print(self, results: dict[str, Any]) -> None:
        for name, block in results["peers"].items():
            self.console.print(
                f"{name}: {block['successes']}/{block['trials']} goals "
                f"({block['success_rate']:.0%}), train {block['train_cpu_s']:.0f} CPU s, "
                f"infer p50 {block['infer_p50_ms']:.2f} ms p99 {block['infer_p99_ms']:.2f} ms")
        self.console.print(json.dumps({"hcc": results["hcc"]["success_rate"]}))
        self.console.print(f"results: {self.out / 'results.json'}")


def _point(n: int, episodes: list[dict[str, Any]], **extra: Any) -> dict[str, Any]:
    from simulator.experiment.report import controller_block

    block = controller_block(episodes)
    return {"demonstrations": n, "success_rate": block["success_rate"],
            "successes": block["successes"], "trials": block["trials"],
            "failure_modes": block["failure_modes"], **extra}

"""The learner levers of issue 13, each switched against the default, over several seeds.

Usage (after a ``roger experiment goal-scoring`` run, whose stream it reuses)::

    python scripts/ablation.py --stream RUN/training-data.npz --out ablation.json \
        [--seeds 0,1,2] [--attempts 1] [--only NAME,...] [--seed S]

``--stream`` also takes a multi-stream run's ``OUT/stream-S/prepared.npz``; ``--seed S`` then
evaluates on that stream's own evaluation seeds (the experiment's ``--seed S``).

For every variant (the default configuration, then one lever changed at a time) it trains
ROGER once per learner seed on the same downsampled demonstration stream, groups the experts
by majority label, and evaluates ROGER experts + HCC transitioner in-process from the 13 start
locations on the experiment's evaluation seeds. It prints a markdown table (goals per seed,
mean success, experts, ARI, purity, failure modes) and writes every row to ``--out`` (JSON).
The HCC is not re-run; divide by its rate from the experiment's ``results.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.blas import pin_blas_threads
from simulator.controllers.transitioner import DEFAULT_RULE, RULES

#: name -> (what it changes, learner parameters replaced, transitioner rule)
VARIANTS: dict[str, tuple[str, dict[str, Any], str]] = {
    "default": ("the default configuration", {}, DEFAULT_RULE),
    "rule-gate": ("transitioner rule gate (highest gate probability)", {}, "gate"),
    "rule-variance": ("transitioner rule variance (lowest predictive variance)", {}, "variance"),
    "rule-support": ("transitioner rule support (the subtask's biggest expert; the default "
                     "before)", {}, "support"),
    "particles-300": ("300 particles", {"particles": 300}, DEFAULT_RULE),
    "merged-groups": ("ROGER's experts merged per group (one expert per majority label)", {},
                      "merged"),
    "choice-oracle": ("choice oracle: among the subtask's experts, the one closest to the "
                      "demonstrator's own command (uses the demonstrator; a diagnostic, not a "
                      "controller)", {}, "choice-oracle"),
    "consolidated": ("ROGER's experts consolidated by the continuity of the command at switches "
                     "between consecutive ticks (label-free; roger_daemon/consolidate.py)", {},
                     "consolidated"),
    "commands-0.05": ("ROGER's experts clustered by their median command, tau 0.05 (label-free; "
                      "roger_daemon/consolidate.py)", {}, "commands"),
    "particles-10": ("10 particles", {"particles": 10}, DEFAULT_RULE),
    "particles-30": ("30 particles", {"particles": 30}, DEFAULT_RULE),
    "min-support-0": ("no minimum support (every expert's gate competes)",
                      {"min_support": 0}, DEFAULT_RULE),
    "sticky-5": ("temporal stickiness kappa = 5", {"sticky_kappa": 5.0}, DEFAULT_RULE),
    "prior-zero": ("zero GP prior mean (instead of each expert's mean)",
                   {"gp_prior_mean": "zero"}, DEFAULT_RULE),
    "tail-kept": ("tail inputs kept (input weights all 1)", {"input_weights": None}, DEFAULT_RULE),
    "noise-1e-3": ("GP noise theta_n = 1e-3", {"theta_n": 1e-3}, DEFAULT_RULE),
    "sticky-20": ("temporal stickiness kappa = 20", {"sticky_kappa": 20.0}, DEFAULT_RULE),
    "lambda0-10": ("gate prior scatter lambda0 = 10", {"lambda0": 10.0}, DEFAULT_RULE),
    "lambda0-100": ("gate prior scatter lambda0 = 100", {"lambda0": 100.0}, DEFAULT_RULE),
    "lambda0-100-gate": ("gate prior scatter lambda0 = 100, rule gate", {"lambda0": 100.0},
                         "gate"),
    "lambda0-0.1": ("gate prior scatter lambda0 = 0.1", {"lambda0": 0.1}, DEFAULT_RULE),
    "shared-0.25": ("each expert also serves every subtask holding >= 25 % of its points "
                    "(labels group experts for the transitioner, as the majority rule does)",
                    {}, "shared-0.25"),
    "alpha-0.05": ("CRP concentration alpha = 0.05 (new experts 10x less readily)",
                   {"alpha": 0.05}, DEFAULT_RULE),
    "split-gates": ("each expert's gate split where its inputs form clusters (label-free, "
                    "roger_daemon/gate_split.py); the labels name each part's group",
                    {}, "split-gates"),
    "split-gates-0.1": ("split gates, the split test's prior scatter 0.1", {},
                        "split-gates-0.1"),
    "split-gates-0.01": ("split gates, the split test's prior scatter 0.01", {},
                         "split-gates-0.01"),
    "split-gates-0.1-8": ("split gates, prior scatter 0.1, up to 8 parts per expert", {},
                          "split-gates-0.1-8"),
    "beacons-dropped": ("input weights 0 on the beacons (and the tail)",
                        {"input_weights": (1.0,) * 9 + (0.0,) * 9 + (1.0,) * 3 + (0.0,) * 2},
                        DEFAULT_RULE),
}


#: (learner parameter changes, seed) -> trained model: variants that only change the
#: transitioner's rule reuse the model instead of training it again
_MODELS: dict[tuple[str, int], Any] = {}


class _ChoiceOracle:
    """The transitioner with the demonstrator's help: among the experts labelled with the
    FSM's subtask, the one whose mean is closest (largest scaled entry) to the HCC's own
    command.  It tells choice failures (some expert of the subtask has the right action) from
    learning failures (none has)."""

    def __init__(self, hcc: Any, model: Any, labels: dict[int, str], y_scale: Any) -> None:
        self.hcc, self.model, self.labels = hcc, model, labels
        self.y_scale = np.asarray(y_scale, dtype=np.float64)

    def reset(self) -> None:
        self.hcc.reset()

    def act(self, x: Any) -> tuple[Any, str]:
        y_hcc, subtask = self.hcc.decide(x)
        mine = [e for e in self.model.predict_multimap(x)
                if self.labels.get(int(e.expert_id)) == subtask]
        if mine:
            err = [float(np.max(np.abs((np.asarray(e.mean) - y_hcc) / self.y_scale)))
                   for e in mine]
            y = np.asarray(mine[int(np.argmin(err))].mean, dtype=np.float64)
        else:
            y = np.asarray(self.model.predict_one(x).mean, dtype=np.float64)
        self.hcc.commit(y)
        return y, subtask


class _Shared:
    """The transitioner over experts that may serve several subtasks: an expert belongs to
    its majority label and to every label holding at least ``share`` of its points. At each
    tick the experts serving the FSM's subtask carry that subtask as their label, so the
    default rule's mixture runs over them (labels group experts only, as for the majority
    rule; nothing is learned from them)."""

    def __init__(self, hcc: Any, model: Any, labels: list[str], share: float) -> None:
        from roger_daemon.labels import majority_labels

        self.hcc, self.model = hcc, model
        assignments = np.asarray(model.assignments()).tolist()
        self.majority = majority_labels(assignments, labels)
        counts: dict[int, Counter[str]] = {}
        for e, lab in zip(assignments, labels, strict=True):
            counts.setdefault(int(e), Counter())[lab] += 1
        self.serves = {e: {lab for lab, n in c.items() if lab and n >= share * sum(c.values())}
                       for e, c in counts.items()}

    def reset(self) -> None:
        self.hcc.reset()

    def act(self, x: Any) -> tuple[Any, str]:
        from protocols import ExpertOutput
        from simulator.controllers.transitioner import transition_command

        _, subtask = self.hcc.decide(x)
        multimap = tuple(
            ExpertOutput(expert=int(e.expert_id), p=float(e.gate_prob), mean=e.mean, var=e.var,
                         n=int(e.n_points),
                         label=subtask if subtask in self.serves.get(int(e.expert_id), ())
                         else self.majority.get(int(e.expert_id), ""))
            for e in self.model.predict_multimap(x))
        fallback = None if multimap else np.asarray(self.model.predict_one(x).mean)
        y, _, _ = transition_command(multimap, fallback, subtask, DEFAULT_RULE)
        self.hcc.commit(y)
        return y, subtask


def _consolidated(rule: str, plan: Any, model: Any, stream: Any, params: Any, seed: int) -> Any:
    """The transitioner over ROGER's experts consolidated without labels (the labels only name
    the consolidated experts' groups afterwards)."""
    from roger_daemon.consolidate import command_groups, consolidate
    from roger_daemon.groups import refit_groups
    from roger_daemon.labels import majority_labels
    from simulator.experiment import inprocess as ip
    from simulator.experiment.pipeline import make_hcc

    if rule == "consolidated":
        merged, _ = consolidate(stream["x"], stream["y"], stream["location"], stream["tick"],
                                model, params=params, seed=seed)
    else:
        group = command_groups(model.assignments(), stream["y"], y_scale=params.y_scale,
                               tau=0.05)
        merged, _ = refit_groups(stream["x"], stream["y"], model, group, params=params,
                                 seed=seed)
    names = majority_labels(np.asarray(merged.assignments()).tolist(), stream["labels"])
    return ip.TransitionerController(make_hcc(plan), merged, names, DEFAULT_RULE)


def _controller(rule: str, plan: Any, model: Any, stream: Any, params: Any, seed: int) -> Any:
    from roger_daemon.labels import majority_labels
    from simulator.experiment import inprocess as ip
    from simulator.experiment.pipeline import make_hcc, merge_expert_groups
    from simulator.experiment.training import Demonstrations

    groups = majority_labels(np.asarray(model.assignments()).tolist(), stream["labels"])
    if rule == "choice-oracle":
        return _ChoiceOracle(make_hcc(plan), model, groups, params.y_scale)
    if rule.startswith("shared-"):
        return _Shared(make_hcc(plan), model, list(stream["labels"]),
                       float(rule.removeprefix("shared-")))
    if rule.startswith("split-gates"):
        from roger_daemon.gate_split import SplitGates

        opts = rule.removeprefix("split-gates").split("-")[1:]  # [prior scatter[, parts]]
        split = SplitGates(model, stream["x"], lambda0=float(opts[0]) if opts else None,
                           max_parts=int(opts[1]) if len(opts) > 1 else 4)
        names = majority_labels(split.assignments().tolist(), stream["labels"])
        print(f"    split gates: {len(split.parts)} parts", flush=True)
        return ip.TransitionerController(make_hcc(plan), split, names, DEFAULT_RULE)
    if rule in ("consolidated", "commands"):
        return _consolidated(rule, plan, model, stream, params, seed)
    if rule == "merged":
        n = len(stream["labels"])
        demos = Demonstrations(x=stream["x"], y=stream["y"], labels=list(stream["labels"]),
                               location=np.zeros(n, dtype=np.int64),
                               tick=np.arange(n, dtype=np.int64), unpaired=0)
        m = merge_expert_groups(demos, model, params, seed)
        return ip.TransitionerController(make_hcc(plan), m.model, m.labels, "support")
    return ip.TransitionerController(make_hcc(plan), model, groups, rule)


def _variant_rows(name: str, stream: Any, seeds: list[int], attempts: int, master: int = 0
                  ) -> dict[str, Any]:
    from roger_daemon.learner import Roger
    from simulator.experiment import goal_scoring as gs
    from simulator.experiment import inprocess as ip
    from simulator.experiment.metrics import segmentation_scores
    from simulator.experiment.pipeline import evaluate_in_process
    from simulator.experiment.training import train

    what, changes, rule = VARIANTS[name]
    parser = argparse.ArgumentParser()
    gs.configure(parser)
    argv = ["--out", "unused", "--in-process", "--attempts", str(attempts),
            "--seed", str(master)]
    argv += ["--rule", rule] if rule in RULES else []
    plan = gs.plan_from_args(parser.parse_args(argv))
    params = replace(gs.learner_params(plan), **changes)  # validated again by the dataclass
    per_seed = []
    for seed in seeds:
        key = (json.dumps(changes, sort_keys=True), seed)
        if key not in _MODELS:
            _MODELS[key] = Roger(d_x=stream["x"].shape[1], d_y=stream["y"].shape[1],
                                 params=params, seed=seed)
            train(_MODELS[key], stream["x"], stream["y"])
        model = _MODELS[key]
        assignments = np.asarray(model.assignments())
        seg = segmentation_scores(assignments.tolist(), stream["labels"])
        ctrl = {"roger": _controller(rule, plan, model, stream, params, seed)}
        eps = evaluate_in_process(plan, ctrl)["roger"]
        modes = Counter(ip.failure_mode(e["outcome"], e, e.get("path_m")) for e in eps)
        per_seed.append({"seed": seed, "goals": sum(bool(e["success"]) for e in eps),
                         "episodes": len(eps), "experts": seg.experts, "ari": seg.ari,
                         "purity": seg.purity, "failure_modes": dict(modes)})
        print(f"  {name} seed {seed}: {per_seed[-1]['goals']}/{len(eps)}", flush=True)
    goals = sum(r["goals"] for r in per_seed)
    trials = sum(r["episodes"] for r in per_seed)
    modes_all: Counter[str] = Counter()
    for r in per_seed:
        modes_all.update(r["failure_modes"])
    return {"variant": name, "what": what, "changes": changes, "rule": rule,
            "goals": goals, "trials": trials, "success_rate": goals / trials,
            "seeds": per_seed, "failure_modes": dict(modes_all)}


def _joined(seeds: list[dict[str, Any]], key: str) -> str:
    return " / ".join(f"{x[key]:.2f}" for x in seeds)


def _markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["| variant | goals per seed | success | experts | ARI | purity | failure modes |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        s = r["seeds"]
        modes = ", ".join(f"{n} {k}" for k, n in sorted(r["failure_modes"].items(),
                                                         key=lambda kv: -kv[1]) if k != "goal")
        lines.append(
            f"| {r['what']} | {' / '.join(str(x['goals']) for x in s)} of "
            f"{s[0]['episodes']} | {r['goals']}/{r['trials']} = {100 * r['success_rate']:.0f} % "
            f"| {' / '.join(str(x['experts']) for x in s)} "
            f"| {_joined(s, 'ari')} | {_joined(s, 'purity')} | {modes} |")
    return "\n".join(lines)


def _load_stream(path: Path) -> dict[str, Any]:
    """x, y, labels, location, tick of a ``training-data.npz`` or a ``prepared.npz``."""
    with np.load(path, allow_pickle=False) as data:
        pre = "stream/" if "stream/x" in data.files else ""
        stream = {k: data[pre + k] for k in ("x", "y")}
        stream["labels"] = [str(s) for s in data[pre + "labels"]]
        n = len(stream["labels"])  # older files: one demonstration, consecutive ticks
        for k, default in (("location", np.zeros(n)), ("tick", np.arange(n))):
            stream[k] = data[pre + k] if pre + k in data.files else default
    return stream


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stream", type=Path, required=True,
                    help="training-data.npz of a goal-scoring run (x, y, labels)")
    ap.add_argument("--out", type=Path, required=True, help="JSON file to write")
    ap.add_argument("--seeds", default="0,1,2", help="learner seeds (default 0,1,2)")
    ap.add_argument("--attempts", type=int, default=1, help="attempts per location (default 1)")
    ap.add_argument("--only", default=",".join(VARIANTS), help="variants to run")
    ap.add_argument("--seed", type=int, default=0,
                    help="the experiment's master seed: its evaluation seeds (default 0)")
    args = ap.parse_args()
    pin_blas_threads()
    names = [n for n in args.only.split(",") if n]
    bad = sorted(set(names) - set(VARIANTS))
    if bad:
        ap.error(f"--only: unknown variants {bad}; expected some of {sorted(VARIANTS)}")
    if args.out.exists():
        ap.error(f"--out: {args.out} exists; choose another path")
    stream = _load_stream(args.stream)
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    t0 = time.monotonic()
    for name in names:
        rows.append(_variant_rows(name, stream, seeds, args.attempts, args.seed))
        args.out.write_text(json.dumps({"stream": str(args.stream), "seeds": seeds,
                                        "attempts": args.attempts, "rows": rows,
                                        "wall_s": round(time.monotonic() - t0, 1)}, indent=1))
    print(_markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

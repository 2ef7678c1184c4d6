"""The experiment's report: ``results.json``, the terminal table, the figures.

``results.json`` (schema ``roger.experiment.goal_scoring/1``) holds at least::

    {"hcc": {"success_rate", "trials", ...}, "roger": {...}, "dpa": {...},
     "oracle": {...}, "roger_seeds": [{"learner_seed", "success_rate", ...}, ...],
     "autonomous": {...}, "autonomous_seeds": [...], "ratio_autonomous_to_hcc",
     "experts", "ari", "nmi", "purity", "seed", "config", "per_location", "paper", ...}

:func:`check_results` validates that shape (used by the tests and by ``--quick`` in CI).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.labels import majority_labels
from simulator.experiment.metrics import segmentation_scores, success_rate

__all__ = ["SCHEMA", "build_results", "check_results", "print_report", "write_figures"]

SCHEMA = "roger.experiment.goal_scoring/1"
#: Above this success rate the unimap baseline is not failing the way the paper says it must.
DPA_ALIASING_LIMIT = 0.15


def _per_location(episodes: Sequence[dict[str, Any]],
                  locations: Sequence[int]) -> list[dict[str, Any]]:
    from simulator.episodes import START_LOCATIONS

    rows = []
    for loc in locations:
        eps = sorted((e for e in episodes if e["location"] == loc),
                     key=lambda e: e["repetition"])
        rows.append({
            "location": loc,
            "name": START_LOCATIONS[loc].name if 0 <= loc < len(START_LOCATIONS) else "",
            "attempts": len(eps),
            "successes": sum(bool(e["success"]) for e in eps),
            "outcomes": [e["outcome"] for e in eps],
            "sim_time_s": [e["sim_time_s"] for e in eps],
        })
    return rows


def controller_block(episodes: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Success rate (Wilson interval), outcomes and failure modes of some episodes."""
    from simulator.experiment.inprocess import failure_mode

    modes = [e.get("failure_mode") or failure_mode(e["outcome"], e, e.get("path_m"))
             for e in episodes]
    out = {**success_rate([bool(e["success"]) for e in episodes]).to_json(),
           "outcomes": dict(Counter(e["outcome"] for e in episodes)),
           "failure_modes": dict(Counter(modes))}
    averaging = averaging_block(episodes, modes)
    if averaging:
        out["averaging"] = averaging
    return out


def averaging_block(episodes: Sequence[dict[str, Any]], modes: Sequence[str]) -> dict[str, Any]:
    """How many failed episodes averaged the multimap (:mod:`.averaging`), by failure mode;
    {} when no episode was measured."""
    from simulator.experiment.averaging import AVERAGED_EPISODE_SHARE

    rows = [(m, float(e["averaged_share"])) for e, m in zip(episodes, modes, strict=True)
            if "averaged_share" in e and not e["success"]]
    if not rows:
        return {}
    by_mode: dict[str, list[float]] = {}
    for m, share in rows:
        by_mode.setdefault(m, []).append(share)
    return {
        "threshold": AVERAGED_EPISODE_SHARE,
        "failed_episodes_measured": len(rows),
        "failed_by_averaging": sum(share >= AVERAGED_EPISODE_SHARE for _, share in rows),
        "by_failure_mode": {m: {"episodes": len(v),
                                "by_averaging": sum(x >= AVERAGED_EPISODE_SHARE for x in v),
                                "mean_averaged_share": round(sum(v) / len(v), 3)}
                            for m, v in sorted(by_mode.items())},
    }


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or math.isnan(a) or math.isnan(b) or b <= 0:
        return None
    return a / b


def _seed_blocks(episodes: dict[str, list[dict[str, Any]]], models: Sequence[tuple[int, Any]],
                 labels: Sequence[str], hcc_rate: float | None) -> list[dict[str, Any]]:
    """One row per learner seed: success, ratio to HCC and the segmentation of its model."""
    from simulator.controllers.hcc import coarse_label

    rows = []
    for k, (seed, model) in enumerate(models):
        a = np.asarray(model.assignments()).tolist()
        seg = segmentation_scores(a, labels)
        coarse = segmentation_scores(a, [coarse_label(s) for s in labels])
        block = controller_block(episodes.get(f"roger:{k}", []))
        merged = controller_block(episodes.get(f"groups:{k}", []))
        rows.append({"learner_seed": seed, **block,
                     "ratio_to_hcc": _ratio(block["success_rate"], hcc_rate),
                     "groups": {"successes": merged["successes"], "trials": merged["trials"],
                                "success_rate": merged["success_rate"],
                                "ratio_to_hcc": _ratio(merged["success_rate"], hcc_rate)},
                     "experts": seg.experts, "ari": seg.ari, "nmi": seg.nmi,
                     "purity": seg.purity, "ari_paper_subtasks": coarse.ari,
                     "experts_per_subtask": seg.experts_per_subtask})
    return rows


def autonomous_seed_blocks(episodes: dict[str, list[dict[str, Any]]],
                           models: Sequence[tuple[int, Any]], hcc_rate: float | None,
                           fsms: Sequence[Any] = (), stream: Any = None, data: Any = None
                           ) -> list[dict[str, Any]]:
    """One row per learner seed of the learned-transitions controller (``autonomous:K``);
    with the FSMs, each row's ``graph`` agreement with the HCC's (labels only for that score:
    :mod:`simulator.experiment.fsm_graph`)."""
    from simulator.experiment.fsm_graph import graph_agreement

    rows = []
    for k, (seed, model) in enumerate(models):
        block = controller_block(episodes.get(f"autonomous:{k}", []))
        row = {"learner_seed": seed, **block,
               "ratio_to_hcc": _ratio(block["success_rate"], hcc_rate)}
        if k < len(fsms) and stream is not None and data is not None:
            experts = majority_labels(np.asarray(model.assignments()).tolist(), stream.labels)
            tick = getattr(data, "tick", None)
            starts = None if tick is None else (np.asarray(tick) == 0).tolist()
            row["graph"] = graph_agreement(fsms[k], experts, list(data.labels), starts)
        rows.append(row)
    return rows


def build_results(*, plan: Any, params: Any, demos: Sequence[dict[str, Any]], data: Any,
                  stream: Any, models: Sequence[tuple[int, Any]],
                  episodes: dict[str, list[dict[str, Any]]], check: dict[str, Any] | None,
                  train_s: float, errors: Sequence[str],
                  mcap: Sequence[str] = (), fsms: Sequence[Any] = ()) -> dict[str, Any]:
    """Everything the run measured, as a JSON-ready dict.

    ``episodes`` maps a controller key (``hcc``, ``dpa``, ``oracle``, ``roger:K`` for the
    model of learner seed number K) to its episode records; ``models`` are the ROGER models
    as ``(learner seed, model)``. The ``roger`` block pools every learner seed's episodes (its
    rate is the mean over seeds); ``roger_seeds`` has one row per seed.
    """
    from simulator.controllers.hcc import coarse_label
    from simulator.experiment.goal_scoring import PAPER
    from simulator.experiment.training import expert_table

    assignments = np.asarray(models[0][1].assignments())
    groups = majority_labels(assignments.tolist(), stream.labels)
    seg = segmentation_scores(assignments.tolist(), stream.labels)
    out: dict[str, Any] = {
        "schema": SCHEMA,
        "seed": plan.seed,
        "seeds": dict(plan.seeds),
        "quick": plan.quick,
        "path": "in-process" if plan.in_process else "zenoh",
        "config": {
            "learner": params.to_mapping(),
            "config_file": plan.config,
            "overrides": list(plan.overrides),
            "experiment": plan.to_json(),
        },
    }
    pooled = {c: [e for k in range(len(models)) for e in episodes.get(f"{c}:{k}", [])]
              for c in ("roger", "groups", "autonomous")}
    blocks = {"hcc": episodes.get("hcc"), "dpa": episodes.get("dpa"),
              "oracle": episodes.get("oracle"), **{c: e or None for c, e in pooled.items()}}
    for c, eps in blocks.items():
        if eps is not None:
            out[c] = controller_block(eps)
    if "oracle" in out:
        out["oracle"]["name"] = "segmentation oracle (one sparse online GP per true subtask)"
    if "groups" in out:
        out["groups"]["name"] = ("ROGER experts merged per group (one expert per majority "
                                 "label, learning ROGER's partition of that group)")
    hcc_rate = out.get("hcc", {}).get("success_rate")
    out["roger_seeds"] = _seed_blocks(episodes, models, stream.labels, hcc_rate)
    if getattr(plan, "gates", "niw") == "split":  # docs/goal-scoring.md, "Split gates"
        out["gates"] = "split: each expert's gate split where its inputs form clusters"
        from simulator.experiment.goal_scoring import CONTROLLER_NAMES

        for c in ("roger", "autonomous"):
            if c in out:
                out[c]["name"] = f"{CONTROLLER_NAMES[c]}, split gates"
    if "autonomous" in out:
        out["autonomous"]["name"] = ("ROGER experts chosen by learned transitions: no HCC, no "
                                     "label at run time (docs/autonomy.md)")
        from simulator.experiment.pipeline import gated

        out["autonomous_seeds"] = autonomous_seed_blocks(
            episodes, gated(plan, stream, models) if fsms else models, hcc_rate, fsms,
            stream, data)
        if fsms:
            from simulator.experiment.fsm_graph import mean_agreement

            out["autonomous_graph_agreement"] = mean_agreement(
                [r["graph"] for r in out["autonomous_seeds"] if "graph" in r])
    for c in ("roger", "oracle", "groups", "autonomous"):
        out[f"ratio_{c}_to_hcc"] = _ratio(out.get(c, {}).get("success_rate"), hcc_rate)
    dpa_rate = out.get("dpa", {}).get("success_rate")
    out["dpa_above_aliasing_limit"] = (
        None if dpa_rate is None or math.isnan(dpa_rate) else bool(dpa_rate > DPA_ALIASING_LIMIT)
    )
    out["experts"] = seg.experts
    out["purity"] = seg.purity
    out["ari"] = seg.ari
    out["nmi"] = seg.nmi
    out["segmentation"] = {
        "learner_seed": models[0][0],
        "largest_expert_share": seg.largest_share,
        "top3_experts_share": seg.top3_share,
        "experts_per_subtask": seg.experts_per_subtask,
        "ari_paper_subtasks": segmentation_scores(
            assignments.tolist(), [coarse_label(s) for s in stream.labels]).ari,
        "subtasks_without_expert": sorted(set(stream.labels) - set(groups.values())),
        "experts_table": expert_table(assignments.tolist(), stream.labels, groups),
    }
    out["per_location"] = {c: _per_location(eps, plan.locations)
                           for c, eps in sorted(episodes.items())}
    out["episodes"] = {c: list(eps) for c, eps in sorted(episodes.items())}
    out["demonstrations"] = {
        "episodes": list(demos),
        "shots_per_location": plan.shots,
        "hcc_success_rate": success_rate([bool(e["success"]) for e in demos]).to_json(),
        "pairs": len(data),
        "pairs_per_subtask": dict(sorted(Counter(data.labels).items())),
        "unpaired_in_logs": data.unpaired,
        "mcap": list(mcap),
    }
    out["training"] = {
        "pairs": len(stream),
        "pairs_per_subtask": dict(sorted(Counter(stream.labels).items())),
        "wall_s": round(train_s, 2),
        "ms_per_pair": round(1000 * train_s / max(1, len(stream) * len(models)), 3),
        "daemon_check": check,
    }
    out["paper"] = dict(PAPER)
    out["errors"] = list(errors)
    return out


def check_results(results: dict[str, Any]) -> list[str]:
    """Problems with the shape of ``results`` (empty when it has every required field)."""
    problems = []
    for c in ("hcc", "roger", "dpa", "oracle"):
        block = results.get(c)
        if not isinstance(block, dict):
            problems.append(f"missing controller block {c!r}")
            continue
        for k in ("success_rate", "trials", "successes", "ci95_low", "ci95_high"):
            if k not in block:
                problems.append(f"{c}.{k} missing")
        if isinstance(block.get("trials"), int) and block["trials"] < 1:
            problems.append(f"{c}.trials < 1")
    for k in ("experts", "ari", "nmi", "purity", "seed", "config", "per_location", "paper",
              "timings_s", "figures"):
        if k not in results:
            problems.append(f"{k} missing")
    if isinstance(results.get("experts"), int) and results["experts"] < 1:
        problems.append("experts < 1")
    for k in ("purity", "nmi"):
        v = results.get(k)
        if isinstance(v, float) and not 0.0 <= v <= 1.0:
            problems.append(f"{k} = {v} outside [0, 1]")
    return problems


def _pct(v: float | None) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{100 * v:.0f}%"


def print_report(console: Any, results: dict[str, Any]) -> None:
    """The results table (rich) beside the paper's numbers."""
    from rich.table import Table

    from simulator.experiment.goal_scoring import CONTROLLER_NAMES

    paper = results["paper"]
    t = Table(title="Goal scoring (paper section IV)", show_lines=False)
    for col in ("controller", "goals / trials", "success", "95% CI (Wilson)", "paper"):
        t.add_column(col, justify="left" if col == "controller" else "right")
    for c in ("hcc", "oracle", "roger", "groups", "autonomous", "dpa"):
        b = results.get(c)
        if not b:
            continue
        t.add_row(CONTROLLER_NAMES[c], f"{b['successes']} / {b['trials']}",
                  _pct(b["success_rate"]),
                  f"{_pct(b['ci95_low'])} - {_pct(b['ci95_high'])}", _pct(paper.get(c)))
        if c in ("roger", "groups", "autonomous") and len(results.get("roger_seeds", [])) > 1:
            seeds = results.get("autonomous_seeds", []) if c == "autonomous" else []
            for row, seg in zip(seeds or results["roger_seeds"], results["roger_seeds"],
                                strict=True):
                r = row if c in ("roger", "autonomous") else row.get("groups", {})
                t.add_row(f"  learner seed {row['learner_seed']}",
                          f"{r.get('successes')} / {r.get('trials')}",
                          _pct(r.get("success_rate", math.nan)),
                          f"ratio {r.get('ratio_to_hcc') or 0:.2f}, ARI {seg['ari']:.2f}", "")
        if c == "dpa" and b.get("averaging"):
            a = b["averaging"]
            t.add_row("  failures that average the multimap",
                      f"{a['failed_by_averaging']} / {a['failed_episodes_measured']}", "",
                      f">= {100 * a['threshold']:.0f}% of ticks", "")
    ratio = results.get("ratio_roger_to_hcc")
    t.add_row("ratio ROGER / HCC", "", "-" if ratio is None else f"{ratio:.2f}", "",
              f"{paper['ratio']:.2f}")
    for c, what in (("oracle", "segmentation oracle"), ("groups", "merged groups"),
                    ("autonomous", "learned transitions")):
        r = results.get(f"ratio_{c}_to_hcc")
        if r is not None:
            t.add_row(f"ratio {what} / HCC", "", f"{r:.2f}", "", "-")
    console.print(t)

    s = Table(title="Segmentation of the training stream (MAP particle)")
    s.add_column("measure")
    s.add_column("value", justify="right")
    s.add_column("paper", justify="right")
    s.add_row("training pairs", str(results["training"]["pairs"]), "<= 4000")
    s.add_row("experts", str(results["experts"]), str(paper["experts"]))
    s.add_row("purity", f"{results['purity']:.3f}", "-")
    s.add_row("adjusted Rand index", f"{results['ari']:.3f}", "-")
    s.add_row("normalised mutual information", f"{results['nmi']:.3f}", "-")
    seg = results["segmentation"]
    for label, share in seg["largest_expert_share"].items():
        s.add_row(f"{label}: share in its largest expert / top 3",
                  f"{share:.2f} / {seg['top3_experts_share'][label]:.2f}", "")
    s.add_row("experts per majority subtask",
              ", ".join(f"{k} {v}" for k, v in seg["experts_per_subtask"].items()), "")
    if seg["subtasks_without_expert"]:
        s.add_row("[red]subtasks with no expert of their own[/red]",
                  ", ".join(seg["subtasks_without_expert"]), "")
    check = results["training"].get("daemon_check")
    if check is not None:
        s.add_row("daemon = offline = replay", "yes" if check.get("ok") else "[red]NO[/red]", "")
    console.print(s)

    tm = Table(title="Timings (wall clock)")
    tm.add_column("phase")
    tm.add_column("seconds", justify="right")
    for k, v in results.get("timings_s", {}).items():
        tm.add_row(k, f"{v:.1f}")
    console.print(tm)
    if results.get("dpa_above_aliasing_limit"):
        console.print("[bold red]The unimap baseline scores above 15 %: the task has lost the "
                      "perceptual aliasing the paper is about.[/bold red]")


def write_figures(out: Path, stream: Any, assignments: npt.NDArray[np.int64],
                  results: dict[str, Any]) -> dict[str, str]:
    """Fig. 7a-c, Fig. 8 and the per-location success rates, as PNG in ``out``."""
    from simulator.experiment.figures import plot_experts_histogram, plot_pca, plot_success

    figs = {
        "fig7_pca": plot_pca(stream.x, stream.y, stream.labels, assignments.tolist(),
                             out / "fig7_pca.png"),
        "fig8_experts": plot_experts_histogram(assignments.tolist(), stream.labels,
                                               out / "fig8_experts.png"),
    }
    per_loc = results["per_location"]
    if per_loc:
        locs = [row["location"] for row in next(iter(per_loc.values()))]
        rates = {c: [row["successes"] / row["attempts"] if row["attempts"] else 0.0
                     for row in rows] for c, rows in per_loc.items()}
        figs["success_per_location"] = plot_success(
            rates, out / "success_per_location.png", locations=locs,
            title="Goals scored per start location "
            f"({next(iter(per_loc.values()))[0]['attempts']} attempt(s) per controller)")
    return {k: str(v) for k, v in figs.items()}

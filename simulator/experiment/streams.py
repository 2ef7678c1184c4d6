"""``roger experiment goal-scoring --streams 0-4``: one configuration, several demonstrations.

A setting chosen on one demonstration stream can fit that stream's luck; the protocol that
cannot runs every stream with the same configuration and reports them side by side, settings
chosen on streams 0-2 and streams 3-4 kept for validation (docs/goal-scoring.md, "Several
demonstration streams"). Stream ``S`` is the single-stream experiment with ``--seed S``
(its own demonstrations, downsampling, learner and evaluation seeds), in-process.

Three phases on ``--jobs`` processes:

1. per stream, :func:`simulator.experiment.bundle.prepare_stream` (demonstrate, train, fit)
   writes ``OUT/stream-S/prepared.npz``;
2. every (stream, controller) pair is one evaluation task (the start locations, then the
   held-out poses), in any process, from the bundle;
3. per stream ``OUT/stream-S/results.json`` (:func:`~simulator.experiment.report.build_results`),
   and ``OUT/results.json`` with the per-stream table and the summary over (stream, learner
   seed): mean ratio to the HCC, worst, a 95 % interval, for streams 0-2 and 3-4 apart.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.atomic import write_json

__all__ = ["CHOOSE", "parse_streams", "run_streams", "stream_plan", "summarise"]

#: The streams settings are chosen on; any other is validation (the issue's protocol).
CHOOSE = (0, 1, 2)
#: The learned rows summarised per (stream, learner seed).
SEEDED = ("roger", "groups", "autonomous")


def parse_streams(text: str) -> tuple[int, ...]:
    """``"0-4"`` or ``"0,2,5"`` -> the stream numbers (each a ``--seed``), in order.

    >>> parse_streams("0-2,7")
    (0, 1, 2, 7)
    """
    out: list[int] = []
    try:
        for part in text.split(","):
            a, _, b = part.strip().partition("-")
            out.extend(range(int(a), int(b) + 1) if b else [int(a)])
    except ValueError:
        raise ValueError(f"--streams must be a list like '0-4' or '0,2,5', got {text!r}"
                         ) from None
    if not out or len(set(out)) != len(out) or min(out) < 0:
        raise ValueError(f"--streams must name distinct streams >= 0, got {text!r}")
    return tuple(out)


def stream_plan(plan: Any, stream: int) -> Any:
    """The single-stream plan of demonstration stream ``stream`` (as ``--seed stream``)."""
    from simulator.experiment.goal_plan import derived_seeds

    return replace(plan, seed=stream, seeds=derived_seeds(stream), streams=(),
                   out=plan.out / f"stream-{stream}", in_process=True)


def _prepare(args: tuple[Any, Any]) -> dict[str, float]:
    from simulator.experiment.bundle import prepare_stream

    plan, params = args
    return prepare_stream(plan, params)


@lru_cache(maxsize=2)
def _bundle(directory: str) -> Any:
    from simulator.experiment.bundle import load_bundle

    return load_bundle(Path(directory))


def _controllers(plan: Any, b: Any) -> dict[str, Any]:
    from simulator.experiment.pipeline import controllers_for

    return controllers_for(plan, b.stream, b.models, b.unimap, b.oracle, b.merged, b.fsms)


def _evaluate(task: tuple[Any, str, bool, Any]) -> tuple[int, str, bool, list[dict[str, Any]]]:
    """One controller of one stream from every start location (or every held-out pose)."""
    from simulator.experiment.pipeline import evaluate_in_process

    plan, key, held_out, starts = task
    controller = _controllers(plan, _bundle(str(plan.out)))[key]
    locs = list(range(len(starts))) if held_out else None
    episodes = evaluate_in_process(plan, {key: controller}, locations=locs,
                                   starts=starts if held_out else None)
    return plan.seed, key, held_out, episodes[key]


def _keys(plan: Any, n_seeds: int) -> list[str]:
    keys = [c for c in ("hcc", "oracle", "dpa") if c in plan.controllers]
    for c in SEEDED:
        if c in plan.controllers:
            keys += [f"{c}:{k}" for k in range(n_seeds)]
    return keys


def run_streams(plan: Any, params: Any, console: Any, starts: list[Any] | None) -> int:
    """The protocol (module docstring); 0 on success."""
    t_all = time.monotonic()
    plans = [stream_plan(plan, s) for s in plan.streams]
    console.print(f"streams {list(plan.streams)} (settings chosen on {list(CHOOSE)}), "
                  f"{plan.learner_seeds} learner seeds, {plan.attempts} attempt(s) x "
                  f"{len(plan.locations)} locations, {plan.jobs} processes")
    with ProcessPoolExecutor(max_workers=plan.jobs) as pool:
        prep = dict(zip(plan.streams, pool.map(_prepare, [(p, params) for p in plans]),
                        strict=True))
        console.log(f"prepared {len(plans)} streams")
        tasks: list[tuple[Any, str, bool, list[Any] | None]] = [
            (p, key, False, None) for p in plans for key in _keys(p, plan.learner_seeds)]
        if starts is not None:
            tasks += [(p, key, True, starts) for p in plans
                      for key in _keys(p, plan.learner_seeds) if key != "dpa"]
        episodes: dict[tuple[int, bool], dict[str, list[dict[str, Any]]]] = {}
        for s, key, held, eps in pool.map(_evaluate, tasks):
            episodes.setdefault((s, held), {})[key] = eps
            won = sum(bool(e["success"]) for e in eps)
            console.log(f"stream {s} {key:>13}{' held-out' if held else ''}: {won}/{len(eps)}")
    per_stream = {}
    for p in plans:
        res = _stream_results(p, params, episodes.get((p.seed, False), {}),
                              episodes.get((p.seed, True)), starts, prep[p.seed])
        write_json(p.out / "results.json", res, default=_json_default)
        per_stream[p.seed] = res
    out = summarise(per_stream)
    out["plan"] = plan.to_json()
    out["timings_s"] = {"total": round(time.monotonic() - t_all, 2)}
    write_json(plan.out / "results.json", out, default=_json_default)
    print_streams(console, out)
    console.print(f"results: {plan.out / 'results.json'}")
    return 0


def _json_default(o: Any) -> Any:
    from simulator.experiment.runner import json_default

    return json_default(o)


class _Data:
    """What build_results reads of the whole demonstration stream."""

    def __init__(self, labels: list[str], tick: Any = None) -> None:
        self.labels = labels
        self.tick = tick  # each pair's tick in its episode (None: an older bundle)
        self.unpaired = 0

    def __len__(self) -> int:
        return len(self.labels)


def _stream_results(plan: Any, params: Any, episodes: dict[str, list[dict[str, Any]]],
                    held: dict[str, list[dict[str, Any]]] | None, starts: Any,
                    prep: dict[str, float]) -> dict[str, Any]:
    from simulator.experiment.report import build_results
    from simulator.experiment.start_poses import held_out_block

    b = _bundle(str(plan.out))
    res = build_results(plan=plan, params=params, demos=b.demos,
                        data=_Data(b.data_labels, b.data_tick), stream=b.stream,
                        models=b.models, episodes=episodes, check=None, train_s=b.train_s,
                        errors=[], fsms=b.fsms)
    if held is not None:
        res["held_out"] = held_out_block(plan, starts, held)
    res["timings_s"] = dict(prep)
    return res


def _interval(values: Sequence[float]) -> list[float] | None:
    """A 95 % Student-t interval of the mean of ``values`` (None for fewer than 2)."""
    from scipy.stats import t as student_t

    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if len(v) < 2:
        return None
    half = float(student_t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v)))
    return [float(v.mean() - half), float(v.mean() + half)]


def _ratios(res: dict[str, Any], c: str, where: str = "") -> list[float | None]:
    src = res.get("held_out", {}) if where else res
    if c == "roger":
        rows = src.get("roger_seeds") or []
    elif c == "groups":
        rows = ([r.get("groups", {}) for r in src.get("roger_seeds") or []] if not where
                else src.get("groups_seeds") or [])
    else:
        rows = src.get(f"{c}_seeds") or []
    hcc = src.get("hcc", {}).get("success_rate")
    out: list[float | None] = []
    for r in rows:
        rate = r.get("success_rate")
        out.append(rate / hcc if hcc and rate is not None else r.get("ratio_to_hcc"))
    return out


def _summary(values: list[float | None]) -> dict[str, Any]:
    v = [x for x in values if x is not None]
    return {"mean_ratio": float(np.mean(v)) if v else None,
            "worst_ratio": float(min(v)) if v else None, "ci95": _interval(v), "n": len(v)}


def summarise(per_stream: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """The multi-stream ``results.json``: the per-stream table and the summaries."""
    table = {}
    for s, res in sorted(per_stream.items()):
        row: dict[str, Any] = {c: res.get(c, {}).get("success_rate")
                               for c in ("hcc", "oracle", "dpa")}
        for c in SEEDED:
            row[f"{c}_ratios"] = _ratios(res, c)
            row[f"{c}_held_out_ratios"] = _ratios(res, c, "held_out")
        row["ari"] = [r["ari"] for r in res.get("roger_seeds", [])]
        row["experts"] = [r["experts"] for r in res.get("roger_seeds", [])]
        row["autonomous_graph_agreement"] = [r["graph"]["graph_agreement"]
                                             for r in res.get("autonomous_seeds") or []
                                             if "graph" in r]
        table[str(s)] = row
    summary: dict[str, Any] = {}
    for c in SEEDED:
        for where in ("", "_held_out"):
            ratios = {int(s): row[f"{c}{where}_ratios"] for s, row in table.items()}
            summary[f"{c}{where}"] = {
                "all": _summary([x for v in ratios.values() for x in v]),
                "choose_0_2": _summary([x for s, v in ratios.items() if s in CHOOSE for x in v]),
                "validation": _summary([x for s, v in ratios.items() if s not in CHOOSE
                                        for x in v])}
    out: dict[str, Any] = {"schema": "roger.experiment.goal_scoring.streams/1",
                           "streams": table, "summary": summary}
    for c in SEEDED:
        out[f"ratio_{c}_to_hcc"] = summary[c]["all"]["mean_ratio"]
    graph = [g for row in table.values() for g in row["autonomous_graph_agreement"]]
    out["autonomous_graph_agreement"] = float(np.mean(graph)) if graph else None
    return out


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def print_streams(console: Any, out: dict[str, Any]) -> None:
    """The per-stream table and the summary."""
    from rich.table import Table

    t = Table(title="Goal scoring over demonstration streams (ratio to the HCC)")
    for col in ("stream", "HCC", "oracle", "ROGER + HCC transitioner", "merged groups",
                "learned transitions", "DPA", "ARI"):
        t.add_column(col, justify="right")
    for s, row in out["streams"].items():
        t.add_row(s, _fmt(row["hcc"]), _fmt(row["oracle"]),
                  " / ".join(_fmt(v) for v in row["roger_ratios"]),
                  " / ".join(_fmt(v) for v in row["groups_ratios"]),
                  " / ".join(_fmt(v) for v in row["autonomous_ratios"]), _fmt(row["dpa"]),
                  " / ".join(_fmt(v) for v in row["ari"]))
    console.print(t)
    for c in SEEDED:
        for split, v in out["summary"][c].items():
            ci = v["ci95"]
            console.print(f"{c:>11} {split:>11}: mean {_fmt(v['mean_ratio'])}, worst "
                          f"{_fmt(v['worst_ratio'])}, 95% CI "
                          f"{'-' if ci is None else f'{ci[0]:.2f} - {ci[1]:.2f}'} "
                          f"(n={v['n']})")

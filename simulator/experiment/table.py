"""``roger experiment table RESULTS.json``: the experiment's results as a Markdown table.

The README's results table is this command's output for the reference run
(``roger experiment goal-scoring --streams 0-4``), so that it is never typed by hand. A
multi-stream ``results.json`` gives one column per stream (the HCC's success rate, the
others' ratio to it, mean over the learner seeds) and the summary over (stream, seed); a
single-stream one gives each row's goals, rate and ratio.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["configure", "markdown", "run"]

ROWS = (("hcc", "HCC (the demonstrator)"), ("oracle", "segmentation oracle (labels)"),
        ("roger", "ROGER experts + HCC transitioner"),
        ("groups", "experts merged per group (labels) + HCC transitioner"),
        ("autonomous", "ROGER experts + learned transitions (no HCC)"),
        ("dpa", "unimap GP (the paper's DPA)"))


def _f(v: float | None, pct: bool = False) -> str:
    if v is None:
        return "-"
    return f"{100 * v:.0f} %" if pct else f"{v:.2f}"


def _mean(values: list[float | None]) -> float | None:
    v = [x for x in values if x is not None]
    return sum(v) / len(v) if v else None


def _streams_table(res: dict[str, Any]) -> str:
    streams = res["streams"]
    head = ["row", *[f"stream {s}" for s in streams], "mean (0-2 / 3-4)", "worst", "95 % CI"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, name in ROWS:
        if key in ("hcc", "oracle", "dpa"):
            cells = [_f(row.get(key), pct=True) for row in streams.values()]
            if key == "oracle":
                cells = [_f(row["oracle"] / row["hcc"] if row.get("oracle") is not None
                            and row.get("hcc") else None) for row in streams.values()]
            lines.append(f"| {name} | " + " | ".join(cells) + " | | | |")
            continue
        cells = [_f(_mean(row[f"{key}_ratios"])) for row in streams.values()]
        s = res["summary"][key]
        ci = s["all"]["ci95"]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {_f(s['all']['mean_ratio'])} ({_f(s['choose_0_2']['mean_ratio'])}"
                     f" / {_f(s['validation']['mean_ratio'])}) | {_f(s['all']['worst_ratio'])}"
                     f" | {'-' if ci is None else f'{ci[0]:.2f} - {ci[1]:.2f}'} |")
    held = [(key, res["summary"].get(f"{key}_held_out", {}).get("all", {}))
            for key in ("roger", "groups", "autonomous")]
    if any(h.get("n") for _, h in held):
        lines.append("| held-out poses (ratio, mean / worst) | "
                     + " | ".join("" for _ in streams) + " | "
                     + "; ".join(f"{k} {_f(h.get('mean_ratio'))} / {_f(h.get('worst_ratio'))}"
                                 for k, h in held) + " | | |")
    return "\n".join(lines)


def _single_table(res: dict[str, Any]) -> str:
    lines = ["| row | goals | success | ratio to HCC |", "|---|---|---|---|"]
    for key, name in ROWS:
        b = res.get(key)
        if not b:
            continue
        ratio = res.get(f"ratio_{key}_to_hcc") if key != "hcc" else 1.0
        lines.append(f"| {name} | {b['successes']}/{b['trials']} | "
                     f"{_f(b['success_rate'], pct=True)} | {_f(ratio)} |")
    return "\n".join(lines)


def markdown(res: dict[str, Any]) -> str:
    """The Markdown table of a goal-scoring ``results.json`` (either kind)."""
    return _streams_table(res) if "streams" in res else _single_table(res)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment table``."""
    parser.add_argument("results", type=Path, help="a goal-scoring results.json")


def run(args: argparse.Namespace) -> int:
    """Print the table; 2 if the file is not a goal-scoring results.json."""
    try:
        res = json.loads(args.results.read_text(encoding="utf-8"))
        if not isinstance(res, dict) or "schema" not in res:
            raise ValueError("no goal-scoring schema")
        text = markdown(res)
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        print(f"roger experiment table: {args.results}: not a goal-scoring results.json "
              f"({exc})", file=sys.stderr)
        return 2
    print(text)
    return 0

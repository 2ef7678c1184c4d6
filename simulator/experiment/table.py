"""``roger experiment table RESULTS.json``: the experiment's results as a Markdown table.

The README's results table is this command's output for the reference run
(``roger experiment goal-scoring --streams 0-4``), so that it is never typed by hand. A
multi-stream ``results.json`` gives one column per stream (the HCC's success rate, the
others' ratio to it, mean over the learner seeds) and the summary over (stream, seed); a
single-stream one gives each row's goals, rate and ratio. ``--peers FILE ...`` adds a table of
``roger experiment peers`` results (docs/peers.md): each peer's success with its 95 % interval,
its ratio to the HCC of its own run, training CPU seconds and p99 inference per tick.
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


def _rows(res: dict[str, Any]) -> list[tuple[str, str]]:
    """:data:`ROWS`, the ROGER rows naming split gates when the run used them."""
    # the run's plan: a multi-stream file's "plan", a single stream's config.experiment
    plan = res.get("plan") or res.get("config", {}).get("experiment", {})
    if plan.get("gates", "niw") != "split":
        return list(ROWS)
    return [(key, name.replace("ROGER experts", "ROGER experts (split gates)"))
            for key, name in ROWS]


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
    for key, name in _rows(res):
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
    for key, name in _rows(res):
        b = res.get(key)
        if not b:
            continue
        ratio = res.get(f"ratio_{key}_to_hcc") if key != "hcc" else 1.0
        lines.append(f"| {name} | {b['successes']}/{b['trials']} | "
                     f"{_f(b['success_rate'], pct=True)} | {_f(ratio)} |")
    return "\n".join(lines)


PEER_NAMES = {"act": "ACT (LeRobot)", "diffusion": "Diffusion Policy (LeRobot)"}


PEERS_HEAD = ("| peer (acts alone) | goals | success (95 % CI) | ratio to HCC | held-out poses "
              "| train CPU s | infer p99 ms |\n|---|---|---|---|---|---|---|")


def peer_rows(res: dict[str, Any]) -> list[str]:
    """The rows of one ``roger experiment peers`` results file (docs/peers.md)."""
    lines = []
    for key, b in res["peers"].items():
        held = b.get("held_out") or {}
        held_s = f"{held['successes']}/{held['trials']}" if held.get("trials") else "-"
        lines.append(
            f"| {PEER_NAMES.get(key, key)}, {b['steps']:,} steps | {b['successes']}/"
            f"{b['trials']} | {_f(b['success_rate'], pct=True)} ({_f(b['ci95_low'], True)}"
            f" - {_f(b['ci95_high'], True)}) | {_f(b.get('ratio_to_hcc'))} | {held_s} | "
            f"{b['train_cpu_s']:,.0f} | {b['infer_p99_ms']:.1f} |")
    return lines


def peers_table(runs: list[dict[str, Any]]) -> str:
    """The peers' table of ``roger experiment peers`` results files."""
    return _peers_of([row for res in runs for row in peer_rows(res)])


def _peers_of(rows: list[str]) -> str:
    return "\n".join([PEERS_HEAD, *rows])


def markdown(res: dict[str, Any]) -> str:
    """The Markdown table of a goal-scoring ``results.json`` (either kind)."""
    return _streams_table(res) if "streams" in res else _single_table(res)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger experiment table``."""
    parser.add_argument("results", type=Path, help="a goal-scoring results.json")
    parser.add_argument("--peers", type=Path, nargs="+", default=[], metavar="FILE",
                        help="roger experiment peers results.json files: their rows follow")


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
    rows: list[str] = []
    for path in args.peers:
        try:
            peer = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(peer, dict) or not isinstance(peer.get("peers"), dict):
                raise ValueError("no 'peers' object")
            rows += peer_rows(peer)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            print(f"roger experiment table: --peers {path}: not a roger experiment peers "
                  f"results.json ({exc})", file=sys.stderr)
            return 2
    if args.peers:
        text += "\n\n" + _peers_of(rows)
    print(text)
    return 0

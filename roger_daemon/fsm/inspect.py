"""The learned automaton, readable: states, transitions and the conditions they fire under.

:func:`describe` turns a :class:`~roger_daemon.fsm.controller.LearnedFSM` into plain JSON
(what ``roger model fsm --json`` writes); :func:`format_fsm` prints it; :func:`draw_fsm` draws
the graph (matplotlib). Nothing here reads a label: the states are expert ids.

A **state** is an expert; its ``ticks`` are the observed ticks spent in it, ``stays`` those
that continued it, ``mean_stay_s`` the mean time in it before a switch. A **transition**
``s -> j`` (``j != s``) has its count, ``p`` = count / every tick observed in ``s`` (the
per-tick switch probability), and its **conditions**: the features whose mean at the switch
differs most from their mean while ``s`` persists, in units of the persisting spread
(docs/autonomy.md, *Reading the automaton*). Transitions from the start row (``-1``) are the
episode starts, when they were learned.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.fsm.controller import START, LearnedFSM

__all__ = ["describe", "draw_fsm", "format_fsm"]


def _conditions(fsm: LearnedFSM, r_switch: int, r_stay: int | None, names: list[str],
                top: int) -> list[dict[str, Any]]:
    t = fsm.transitions
    mu = t.mu[r_switch]
    if r_stay is None:
        return [{"feature": names[i], "mean": round(float(mu[i]), 3)}
                for i in np.argsort(-np.abs(mu))[:top]]
    ref = t.mu[r_stay]
    sd = np.sqrt(np.maximum(np.diag(t.lam[r_stay]) / (t.count[r_stay] + 1.0), 1e-12))
    z = (mu - ref) / sd
    return [{"feature": names[i], "mean": round(float(mu[i]), 3),
             "while_staying": round(float(ref[i]), 3), "z": round(float(z[i]), 2)}
            for i in np.argsort(-np.abs(z))[:top]]


def describe(fsm: LearnedFSM, top: int = 3) -> dict[str, Any]:
    """States, transitions and their ``top`` conditions as a JSON-ready dict."""
    t = fsm.transitions
    names = fsm.spec.names()
    rows = {(int(s), int(j)): r for r, (s, j) in enumerate(t.pairs.tolist())}
    out_of: dict[int, int] = defaultdict(int)
    for (s, _), r in rows.items():
        out_of[s] += int(t.count[r])
    ids = sorted({j for _, j in rows} | {s for s, _ in rows if s != START})
    states = []
    for s in ids:
        stays = int(t.count[rows[(s, s)]]) if (s, s) in rows else 0
        leaves = out_of.get(s, 0) - stays
        states.append({"id": s, "ticks": out_of.get(s, 0), "stays": stays, "leaves": leaves,
                       "mean_stay_s": round((stays + leaves) / max(leaves, 1) / fsm.spec.hz, 2)})
    transitions = []
    for (s, j), r in sorted(rows.items(), key=lambda kv: (kv[0][0], -int(t.count[kv[1]]))):
        if s == j:
            continue
        n = int(t.count[r])
        transitions.append({"from": s, "to": j, "count": n,
                            "p": round(n / max(out_of[s], 1), 5),
                            "conditions": _conditions(fsm, r, rows.get((s, s)), names, top)})
    return {"kind": "roger.fsm", "states": states, "transitions": transitions,
            "features": names, "n_observed": fsm.n_observed, "hz": fsm.spec.hz,
            "start_row": START in out_of}


def format_fsm(desc: dict[str, Any], limit: int = 40) -> str:
    """:func:`describe`'s dict as text: a table of states, then the ``limit`` most frequent
    transitions with their conditions."""
    lines = [f"learned transitions: {len(desc['states'])} states, {len(desc['transitions'])} "
             f"transitions, {desc['n_observed']} observed ticks, {len(desc['features'])} "
             "features", "", f"{'state':>6} {'ticks':>7} {'stays':>7} {'mean stay s':>11}"]
    for s in desc["states"]:
        lines.append(f"{s['id']:>6} {s['ticks']:>7} {s['stays']:>7} {s['mean_stay_s']:>11}")
    lines += ["", "transition        count  P/tick   when (feature: at switch, while staying)"]
    shown = sorted(desc["transitions"], key=lambda tr: -tr["count"])[:limit]
    for tr in shown:
        src = "start" if tr["from"] == START else str(tr["from"])
        when = "; ".join(f"{c['feature']} {c['mean']:+.2f}"
                         + (f" ({c['while_staying']:+.2f})" if "while_staying" in c else "")
                         for c in tr["conditions"])
        lines.append(f"{src:>6} -> {tr['to']:<6} {tr['count']:>6}  {tr['p']:<7.4f}  {when}")
    if len(desc["transitions"]) > limit:
        lines.append(f"... {len(desc['transitions']) - limit} rarer transitions (--json)")
    return "\n".join(lines)


def draw_fsm(desc: dict[str, Any], path: str | Path, min_count: int = 1) -> None:
    """The automaton as a picture: states on a circle (area ~ ticks), an arrow per transition
    seen at least ``min_count`` times (width ~ log count)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    states = desc["states"]
    n = max(len(states), 1)
    pos = {s["id"]: (math.cos(2 * math.pi * k / n), math.sin(2 * math.pi * k / n))
           for k, s in enumerate(states)}
    pos[START] = (0.0, 0.0)
    most = max((s["ticks"] for s in states), default=1) or 1
    fig, ax = plt.subplots(figsize=(7, 7))
    for tr in desc["transitions"]:
        if tr["count"] < min_count or tr["from"] not in pos:
            continue
        (x0, y0), (x1, y1) = pos[tr["from"]], pos[tr["to"]]
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0),
                    arrowprops={"arrowstyle": "->", "lw": 0.4 + math.log1p(tr["count"]) / 2,
                                "alpha": 0.6, "connectionstyle": "arc3,rad=0.15",
                                "shrinkA": 14, "shrinkB": 14})
    for s in states:
        x, y = pos[s["id"]]
        ax.scatter([x], [y], s=200 + 1800 * s["ticks"] / most, zorder=3, alpha=0.85)
        ax.text(x, y, f"{s['id']}\n{s['mean_stay_s']}s", ha="center", va="center", zorder=4,
                fontsize=8)
    ax.set_title(f"learned transitions: {len(states)} states, {len(desc['transitions'])} "
                 "transitions (state: expert id, mean stay)")
    ax.set_xlim(-1.4, 1.4)
    ax.set_ylim(-1.4, 1.4)
    ax.set_aspect("equal")
    ax.axis("off")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)

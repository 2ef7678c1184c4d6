"""Top-down plots of episodes: robot path coloured by subtask, ball path, goals, beacons.

``python -m simulator.plot --locations 0,3,6,8,11,12 --seed 1 --out figures/episodes.png``
runs the HCC in-process (fast vision unless ``--vision rendered``) and saves a PNG.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from simulator.config import FieldConfig, load_config
from simulator.controllers.hcc import HCC, HCCParams
from simulator.episodes import (
    START_LOCATIONS,
    EpisodeResult,
    SoccerSim,
    Trace,
    parse_locations,
    run_episode,
)

__all__ = ["SUBTASK_COLOURS", "draw_field", "main", "plot_episodes"]

SUBTASK_COLOURS = {"seek": "#7f7f7f", "trap": "#1f77b4", "aim": "#9467bd", "kick": "#d62728"}


def draw_field(ax: object, f: FieldConfig) -> None:
    """Field lines, goals (in their colours), beacons."""
    import matplotlib.patches as mpatches

    hl, hw = f.length / 2, f.width / 2
    ax.add_patch(  # type: ignore[attr-defined]
        mpatches.Rectangle(
            (-hl - f.fringe_end, -hw - f.fringe_side),
            f.length + 2 * f.fringe_end,
            f.width + 2 * f.fringe_side,
            color="#2e7d32",
            alpha=0.25,
            lw=0,
        )
    )
    ax.add_patch(mpatches.Rectangle((-hl, -hw), f.length, f.width, fill=False, ec="white", lw=2))  # type: ignore[attr-defined]
    ax.plot([0, 0], [-hw, hw], color="white", lw=1.5)  # type: ignore[attr-defined]
    ax.add_patch(mpatches.Circle((0, 0), 0.18, fill=False, ec="white", lw=1.5))  # type: ignore[attr-defined]
    other = "yellow" if f.attack == "blue" else "blue"
    colours = {"blue": "#4fa3ff", "yellow": "#f2d21b"}
    for sx, c in ((1, f.attack), (-1, other)):
        x0 = hl if sx > 0 else -hl - f.goal_depth
        ax.add_patch(  # type: ignore[attr-defined]
            mpatches.Rectangle(
                (x0, -f.goal_width / 2), f.goal_depth, f.goal_width, color=colours[c], alpha=0.9
            )
        )
    for sx in (-1, 1):
        for sy in (-1, 1):
            ax.add_patch(  # type: ignore[attr-defined]
                mpatches.Circle(
                    (sx * (hl - f.beacon_from_goal_line), sy * (hw + f.beacon_outside)),
                    0.07,
                    color="#ff66b3",
                )
            )
    ax.set_xlim(-hl - 0.4, hl + 0.4)  # type: ignore[attr-defined]
    ax.set_ylim(-hw - 0.3, hw + 0.3)  # type: ignore[attr-defined]
    ax.set_aspect("equal")  # type: ignore[attr-defined]
    ax.set_xticks([])  # type: ignore[attr-defined]
    ax.set_yticks([])  # type: ignore[attr-defined]


def plot_episodes(
    episodes: Sequence[tuple[EpisodeResult, Trace]], f: FieldConfig, path: str | Path
) -> Path:
    """One panel per episode; saves a PNG at ``path`` and returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    n = len(episodes)
    cols = min(3, max(1, n))
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(5.2 * cols, 3.9 * rows + 0.9), squeeze=False, layout="constrained"
    )
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax, (res, tr) in zip(axes.ravel(), episodes, strict=False):
        draw_field(ax, f)
        rx = np.array([t["robot_x"] for t in tr.truth])
        ry = np.array([t["robot_y"] for t in tr.truth])
        bx = np.array([t["ball_x"] for t in tr.truth])
        by = np.array([t["ball_y"] for t in tr.truth])
        if len(rx) > 1:
            segs = np.stack([np.c_[rx[:-1], ry[:-1]], np.c_[rx[1:], ry[1:]]], axis=1)
            cols_ = [SUBTASK_COLOURS.get(lab, "black") for lab in tr.labels[:-1]]
            ax.add_collection(LineCollection(list(segs), colors=cols_, linewidths=2.2))
            ax.plot(bx, by, color="#ff7f0e", lw=1.2, ls="--")
            labels = np.array(tr.labels)
            # subtasks done turning in place: seek as grey rings, aim as large purple rings
            m = labels == "seek"
            ax.scatter(
                rx[m],
                ry[m],
                s=90,
                facecolors="none",
                edgecolors=SUBTASK_COLOURS["seek"],
                linewidths=1.2,
                zorder=3,
            )
            m = labels == "aim"
            ax.scatter(
                rx[m],
                ry[m],
                s=260,
                facecolors="none",
                edgecolors=SUBTASK_COLOURS["aim"],
                linewidths=1.6,
                zorder=3,
            )
            prev = np.concatenate([np.array([""], dtype=object), labels[:-1]])
            starts = np.flatnonzero((labels == "kick") & (prev != "kick"))
            ax.scatter(
                rx[starts],
                ry[starts],
                s=140,
                marker="*",
                color=SUBTASK_COLOURS["kick"],
                edgecolors="black",
                linewidths=0.6,
                zorder=4,
            )
            yaw = tr.truth[0]["robot_yaw"]
            ax.annotate(
                "",
                xy=(rx[0] + 0.3 * math.cos(yaw), ry[0] + 0.3 * math.sin(yaw)),
                xytext=(rx[0], ry[0]),
                arrowprops={"arrowstyle": "->", "lw": 1.5},
            )
            ax.plot(rx[0], ry[0], "ks", ms=6)
            ax.plot(bx[0], by[0], "o", color="#ff7f0e", mec="black", ms=7)
            ax.plot(bx[-1], by[-1], "X", color="#ff7f0e", mec="black", ms=9)
        loc = START_LOCATIONS[res.location]
        ax.set_title(
            f"location {res.location} ({loc.name}): {res.outcome}, {res.sim_time_s:.1f} s",
            fontsize=10,
        )
    handles = [Line2D([], [], color=c, lw=3, label=s) for s, c in SUBTASK_COLOURS.items()]
    handles += [
        Line2D(
            [],
            [],
            marker="o",
            mfc="none",
            mec=SUBTASK_COLOURS["seek"],
            ms=9,
            ls="",
            label="seeking (in place)",
        ),
        Line2D(
            [],
            [],
            marker="o",
            mfc="none",
            mec=SUBTASK_COLOURS["aim"],
            ms=12,
            mew=1.6,
            ls="",
            label="aiming (in place)",
        ),
        Line2D(
            [], [], marker="*", color=SUBTASK_COLOURS["kick"], mec="k", ms=12, ls="", label="kick"
        ),
        Line2D([], [], color="#ff7f0e", ls="--", label="ball path"),
        Line2D([], [], marker="s", color="k", ls="", label="robot start"),
        Line2D([], [], marker="o", color="#ff7f0e", mec="k", ls="", label="ball start"),
        Line2D([], [], marker="X", color="#ff7f0e", mec="k", ls="", label="ball end"),
    ]
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncol=(len(handles) + 1) // 2,
        fontsize=9,
        frameon=False,
    )
    fig.suptitle(
        f"HCC episodes, attacking the {f.attack} goal (+x); robot path coloured by subtask"
    )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run HCC episodes in-process and plot them."""
    ap = argparse.ArgumentParser(prog="python -m simulator.plot", description=__doc__)
    ap.add_argument("--locations", default="0,3,6,8,11,12")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--vision", choices=("rendered", "fast"), default="fast")
    ap.add_argument("--config", default=None, help="TOML task config (e.g. configs/aibo.toml)")
    ap.add_argument("--out", default="figures/sim_episodes.png")
    args = ap.parse_args(argv)
    cfg = load_config(args.config)
    sim = SoccerSim(cfg, vision=args.vision)
    hcc = HCC(HCCParams(attack=cfg.field.attack))
    runs = []
    for i, loc in enumerate(parse_locations(args.locations)):
        tr = Trace()
        res = run_episode(sim, hcc, loc, args.seed, episode=i, trace=tr)
        print(res.to_map(), file=sys.stderr)
        runs.append((res, tr))
    sim.close()
    print(plot_episodes(runs, cfg.field, args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

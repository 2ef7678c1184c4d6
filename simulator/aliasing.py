"""Measure perceptual aliasing in demonstration data: near-identical inputs, conflicting actions.

Two demonstration points are *near-identical* when every one of their 23 perception entries
differs by at most ``eps`` (Chebyshev distance; blob x/y/size are in [-1, 1], angles in
radians). Their actions *conflict* when the action indicators decode differently (kick / trap /
none) or when some action entry differs by more than ``conflict`` of its scale (walk: the walk
limits; head and tail: half their joint range). Points of the same episode closer than
``min_gap`` ticks are not paired (consecutive frames are trivially alike).

The paper's multimap shows up as conflicting pairs *across* subtasks (seek/aim/kick all see
no ball and the same head pose); :func:`measure_aliasing` reports, per unordered subtask pair,
how many near-identical pairs there are and which fraction conflict, plus how often the ball
and the goal are seen at once while aiming (0 by construction: the held ball is under the chin).

``python -m simulator.aliasing --seeds 0`` runs the HCC in-process from the 13 locations and
prints the report as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from protocols.aibo import blob_slice, decode_indicator

__all__ = ["ACTION_SCALE", "conflict_within", "conflicting", "main", "measure_aliasing"]

#: Scale of each action entry for the conflict test: walk limits (m/s, rad/s), half the head
#: and tail joint ranges (rad), 1 for the indicator.
ACTION_SCALE = np.array(
    [
        0.225,
        0.17,
        2.1,
        math.radians(37.5),
        math.radians(88.0),
        math.radians(30.0),
        math.radians(45.0),
        math.radians(27.5),
        1.0,
    ]
)


def _indicators(values: np.ndarray) -> np.ndarray:
    """The decoded action indicator (``kick``/``trap``/``none``) of each value, same shape."""
    v = np.asarray(values, dtype=np.float64)
    return np.array([decode_indicator(float(e)) for e in v.reshape(-1)]).reshape(v.shape)


def conflicting(ya: np.ndarray, yb: np.ndarray, conflict: float = 0.5) -> np.ndarray:
    """Row-wise: do actions ``ya[i]`` and ``yb[i]`` conflict?"""
    ya = np.atleast_2d(ya)
    yb = np.atleast_2d(yb)
    big = np.max(np.abs(ya[:, :8] - yb[:, :8]) / ACTION_SCALE[:8], axis=1) > conflict
    out: np.ndarray = big | (_indicators(ya[:, 8]) != _indicators(yb[:, 8]))
    return out


def conflict_within(sets: np.ndarray, conflict: float = 0.5) -> np.ndarray:
    """Per set of actions ``sets[i]`` (shape ``(sets, members, 9)``): do any two members
    conflict by :func:`conflicting`'s rule? (Some entry's range over the set exceeds
    ``conflict`` of its scale, or the members' indicators decode differently.)"""
    s = np.asarray(sets, dtype=np.float64)
    spread = (s[:, :, :8].max(axis=1) - s[:, :, :8].min(axis=1)) / ACTION_SCALE[:8]
    names = _indicators(s[:, :, 8])
    out: np.ndarray = (spread.max(axis=1) > conflict) | (names != names[:, :1]).any(axis=1)
    return out


def measure_aliasing(
    X: np.ndarray,
    Y: np.ndarray,
    labels: Sequence[str] | np.ndarray,
    episodes: Sequence[int] | np.ndarray | None = None,
    ticks: Sequence[int] | np.ndarray | None = None,
    *,
    eps: float = 0.05,
    conflict: float = 0.5,
    min_gap: int = 15,
    max_points: int = 12000,
    rng: np.random.Generator | None = None,
    attack: str = "blue",
) -> dict[str, Any]:
    """The aliasing report of demonstration data (see the module docstring).

    ``episodes``/``ticks`` (same length as ``X``) identify temporal neighbours; without them
    the row index is the tick and everything is one episode. At most ``max_points`` rows
    (drawn with ``rng``) are paired.
    """
    X = np.asarray(X, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    lab = np.asarray(labels, dtype=object)
    n = len(X)
    if not (len(Y) == n == len(lab)):
        raise ValueError("X, Y and labels must have the same length")
    ep = np.zeros(n, dtype=np.int64) if episodes is None else np.asarray(episodes, dtype=np.int64)
    tk = np.arange(n) if ticks is None else np.asarray(ticks, dtype=np.int64)
    # co-visibility of ball and goal while aiming, on all the data
    aim = lab == "aim"
    ball_seen = X[:, blob_slice("ball")][:, 2] > 0
    goal_seen = X[:, blob_slice(f"{attack}_goal")][:, 2] > 0
    report: dict[str, Any] = {
        "points": int(n),
        "eps": eps,
        "conflict": conflict,
        "min_gap": min_gap,
        "aim_points": int(aim.sum()),
        "aim_ball_seen_fraction": float(ball_seen[aim].mean()) if aim.any() else 0.0,
        "aim_ball_and_goal_seen_fraction": (
            float((ball_seen & goal_seen)[aim].mean()) if aim.any() else 0.0
        ),
    }
    idx = np.arange(n)
    if n > max_points:
        idx = np.sort((rng or np.random.default_rng(0)).choice(n, max_points, replace=False))
    tree = cKDTree(X[idx])
    pairs = tree.query_pairs(eps, p=np.inf, output_type="ndarray")
    if len(pairs):
        i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]
        keep = (ep[i] != ep[j]) | (np.abs(tk[i] - tk[j]) >= min_gap)
        i, j = i[keep], j[keep]
    else:
        i = j = np.zeros(0, dtype=np.int64)
    conf = conflicting(Y[i], Y[j], conflict) if len(i) else np.zeros(0, dtype=bool)
    report["sampled_points"] = int(len(idx))
    report["pairs"] = int(len(i))
    report["conflicting_pairs"] = int(conf.sum())
    report["conflict_fraction"] = float(conf.mean()) if len(i) else 0.0
    cross = lab[i] != lab[j]
    report["cross_subtask_pairs"] = int(cross.sum())
    report["cross_subtask_conflict_fraction"] = float(conf[cross].mean()) if cross.any() else 0.0
    report["within_subtask_conflict_fraction"] = (
        float(conf[~cross].mean()) if (~cross).any() else 0.0
    )
    per_pair: dict[str, dict[str, float]] = {}
    present = _label_order(lab)
    for k, a in enumerate(present):
        for b in present[k:]:
            m = ((lab[i] == a) & (lab[j] == b)) | ((lab[i] == b) & (lab[j] == a))
            if m.any():
                per_pair[f"{a}/{b}"] = {
                    "pairs": int(m.sum()),
                    "conflicts": int(conf[m].sum()),
                    "fraction": round(float(conf[m].mean()), 4),
                }
    within = {
        a: per_pair[f"{a}/{a}"]["fraction"] for a in present if f"{a}/{a}" in per_pair
    }
    report["within_subtask_conflict_by_subtask"] = within
    report["max_within_subtask_conflict"] = max(within.values()) if within else 0.0
    report["per_subtask_pair"] = per_pair
    return report


def _label_order(labels: np.ndarray) -> list[str]:
    """Labels present, in the demonstrator's order (``simulator.controllers.hcc.LABELS``),
    then others."""
    from simulator.controllers.hcc import LABELS

    present = set(labels.tolist())
    return [s for s in LABELS if s in present] + sorted(present - set(LABELS))


def main(argv: Sequence[str] | None = None) -> int:
    """Collect one shot per location with the HCC (in-process) per seed; print the report."""
    from simulator.controllers.hcc import HCC
    from simulator.episodes import START_LOCATIONS, SoccerSim, Trace, run_episode

    ap = argparse.ArgumentParser(prog="python -m simulator.aliasing", description=__doc__)
    ap.add_argument("--seeds", default="0", help="comma list of seeds (one shot per location each)")
    ap.add_argument("--vision", choices=("rendered", "fast"), default="fast")
    ap.add_argument("--eps", type=float, default=0.05)
    args = ap.parse_args(argv)
    sim = SoccerSim(vision=args.vision)
    hcc = HCC()
    xs, ys, labs, eps_, tks = [], [], [], [], []
    k = 0
    for seed in (int(s) for s in args.seeds.split(",")):
        for loc in range(len(START_LOCATIONS)):
            tr = Trace()
            run_episode(sim, hcc, loc, seed, trace=tr)
            X, Y, L = tr.arrays()
            xs.append(X)
            ys.append(Y)
            labs.append(L)
            eps_.append(np.full(len(X), k))
            tks.append(np.arange(len(X)))
            k += 1
    sim.close()
    rep = measure_aliasing(
        np.concatenate(xs),
        np.concatenate(ys),
        np.concatenate(labs),
        np.concatenate(eps_),
        np.concatenate(tks),
        eps=args.eps,
    )
    print(json.dumps(rep, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

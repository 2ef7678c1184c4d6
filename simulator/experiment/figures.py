"""The paper's figures (Fig. 7a-c, Fig. 8) and per-location success rates, as PNG files."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt

from protocols.aibo import SUBTASKS
from roger_daemon.labels import majority_labels

__all__ = [
    "SUBTASK_COLOURS",
    "expert_colours",
    "pca3",
    "plot_experts_histogram",
    "plot_pca",
    "plot_success",
]

SUBTASK_COLOURS = {"seek": "tab:blue", "trap": "tab:orange", "aim": "tab:green", "kick": "tab:red"}


def pca3(data: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Project rows of ``data`` on their first 3 principal components (standardised columns)."""
    z = data - data.mean(axis=0)
    sd = z.std(axis=0)
    z = z / np.where(sd > 0, sd, 1.0)
    _, _, vt = np.linalg.svd(z, full_matrices=False)
    out: npt.NDArray[np.float64] = z @ vt[:3].T
    return out


def expert_colours(assignments: npt.NDArray[np.int64]) -> dict[int, tuple[float, float, float]]:
    """A colour per expert, largest expert first, hues spread by the golden ratio (so that
    experts close in size differ in colour); independent of the subtask colours."""
    from matplotlib.colors import hsv_to_rgb

    ids, counts = np.unique(assignments, return_counts=True)
    order = [int(e) for _, e in sorted(zip(-counts, ids, strict=True))]
    out = {}
    for i, e in enumerate(order):
        hue = (0.12 + 0.618034 * i) % 1.0
        rgb = hsv_to_rgb((hue, 0.55 + 0.35 * (i % 2), 0.95 - 0.25 * ((i // 2) % 2)))
        out[e] = (float(rgb[0]), float(rgb[1]), float(rgb[2]))
    return out


def _colour(label: str) -> str:
    """Colour of the paper's subtask a demonstrator label belongs to
    (simulator.controllers.hcc.COARSE)."""
    from simulator.controllers.hcc import coarse_label

    return SUBTASK_COLOURS.get(coarse_label(label), "tab:gray")


def plot_pca(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    labels: Sequence[str],
    assignments: Sequence[int],
    out: Path,
) -> Path:
    """Fig. 7: the joint (x, y) data in 3-D PCA coloured (a) by subtask, (b) by expert,
    (c) by the subtask group of each expert (its majority label)."""
    p = pca3(np.hstack([x, y]))
    experts = np.asarray(assignments)
    groups = majority_labels(experts.tolist(), list(labels))
    uniq = sorted(set(experts.tolist()))
    expert_colour = expert_colours(experts)
    fig = plt.figure(figsize=(16, 6))
    panels = [
        ("(a) by demonstrated subtask", [_colour(s) for s in labels]),
        (f"(b) by ROGER expert ({len(uniq)} expert{'s' if len(uniq) != 1 else ''})",
         [expert_colour[e] for e in experts]),
        ("(c) experts grouped by majority subtask", [_colour(groups[e]) for e in experts]),
    ]
    for i, (title, colours) in enumerate(panels):
        ax = fig.add_subplot(1, 3, i + 1, projection="3d")
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], c=colours, s=4, alpha=0.7, linewidths=0)
        ax.set_xlabel("PC1")
        ax.set_ylabel("PC2")
        ax.set_zlabel("PC3")
        # 3-D axes put their own titles inside the (clipped) box: label the panel instead
        fig.text((i + 0.5) / 3, 0.95, title, ha="center", va="top", fontsize=12)
    handles = [
        plt.Line2D([], [], marker="o", ls="", color=_colour(s), label=s) for s in SUBTASKS
    ]
    fig.legend(handles=handles, loc="lower center", ncol=len(SUBTASKS))
    fig.suptitle("Demonstration data, PCA of the joint (perception, action) space",
                 fontsize=13, y=0.995)
    fig.subplots_adjust(left=0.01, right=0.97, bottom=0.08, top=0.9, wspace=0.08)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_experts_histogram(assignments: Sequence[int], labels: Sequence[str], out: Path) -> Path:
    """Fig. 8: data per expert, stacked by subtask (experts in id order)."""
    experts = np.asarray(assignments)
    from simulator.controllers.hcc import coarse_label

    lab = np.asarray([coarse_label(s) for s in labels])
    uniq = sorted(set(experts.tolist()))
    pos = np.arange(len(uniq))
    fig, ax = plt.subplots(figsize=(max(8.0, 0.18 * len(uniq) + 4), 4.5))
    bottom = np.zeros(len(uniq))
    for s in SUBTASKS:
        counts = np.array([np.sum((experts == e) & (lab == s)) for e in uniq], dtype=float)
        ax.bar(pos, counts, bottom=bottom, color=_colour(s), label=s, width=0.85)
        bottom += counts
    ax.set_xticks(pos)
    ax.set_xticklabels([str(e) for e in uniq], rotation=90, fontsize=6)
    ax.set_xlabel("expert id (MAP particle)")
    ax.set_ylabel("data points")
    ax.set_title(f"Data per expert, coloured by subtask ({len(uniq)} experts)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_success(
    per_location: Mapping[str, Sequence[float]],
    out: Path,
    *,
    title: str = "",
    locations: Sequence[int] | None = None,
) -> Path:
    """Success rate per start location, one bar group per location, one bar per controller.

    ``locations`` labels the groups (default 0, 1, ...). Keys ``NAME:K`` (one model per
    learner seed, equal attempts) are pooled into one bar ``NAME`` (their mean rate).
    """
    families: dict[str, list[Sequence[float]]] = {}
    for key, rates in per_location.items():
        families.setdefault(key.split(":")[0], []).append(rates)
    pooled: dict[str, list[float]] = {
        (f"{n} ({len(v)} seeds)" if len(v) > 1 else n):
        [float(r) for r in np.mean(np.asarray(v, dtype=float), axis=0)]
        for n, v in families.items()}
    names = list(pooled)
    n_loc = max((len(v) for v in pooled.values()), default=0)
    fig, ax = plt.subplots(figsize=(max(7.0, 0.7 * n_loc + 3), 4))
    width = 0.8 / max(1, len(names))
    for i, name in enumerate(names):
        bars = ax.bar(np.arange(len(pooled[name])) + i * width, pooled[name], width=width,
                      label=name)
        ax.bar_label(bars, labels=[f"{100 * v:.0f}%" for v in pooled[name]], fontsize=7,
                     padding=1)
    ax.set_xticks(np.arange(n_loc) + 0.4 - width / 2)
    labels = [str(v) for v in locations] if locations is not None else []
    labels += [str(i) for i in range(len(labels), n_loc)]
    ax.set_xticklabels(labels[:n_loc])
    ax.set_xlabel("start location")
    ax.set_ylabel("success rate")
    ax.set_ylim(0, 1.12)
    ax.set_title(title or "Success per start location")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out

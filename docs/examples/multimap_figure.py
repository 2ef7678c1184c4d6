"""Draw the README's concept picture: one input, two demonstrated actions (a multimap).

The data of ``learner_quickstart.py`` (y = +sqrt(x) and y = -sqrt(x), demonstrated in turns)
learned by ROGER with the recommended settings and by one sparse online GP (the paper's DPA).
Each of ROGER's experts is drawn where its gate gives it at least 10 % of the probability;
the one GP averages the two branches. Run it:

    python docs/examples/multimap_figure.py --out docs/figures/multimap.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from roger_daemon.learner import Roger, RogerParams, UnimapGP


def main() -> None:
    """Learn the two-branch stream with both models and draw them."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/figures/multimap.png"),
                    help="the PNG to write (default docs/figures/multimap.png)")
    out = ap.parse_args().out
    rng = np.random.default_rng(0)
    n = 400
    x = rng.uniform(0.0, 1.0, size=(n, 1))
    subtask = np.arange(n) % 2
    y = np.where(subtask[:, None] == 0, 1.0, -1.0) * np.sqrt(x)
    y += rng.normal(0.0, 0.02, size=y.shape)
    params = RogerParams.preset("default", x_ranges=[(0.0, 1.0)], y_ranges=[(-1.0, 1.0)])
    roger = Roger(d_x=1, d_y=1, params=params, seed=0)
    dpa = UnimapGP(d_x=1, d_y=1, params=params, seed=0)
    for xi, yi in zip(x, y, strict=True):
        roger.learn_one(xi, yi)
        dpa.learn_one(xi, yi)

    grid = np.linspace(0.0, 1.0, 101)
    branches: dict[int, list[tuple[float, float]]] = {}
    for g in grid:
        for b in roger.predict_multimap(np.array([g])):
            if b.gate_prob >= 0.1:
                branches.setdefault(b.expert_id, []).append((g, float(b.mean[0])))
    fig, ax = plt.subplots(figsize=(7.0, 3.6))
    ax.scatter(x[:, 0], y[:, 0], s=6, c=np.where(subtask == 0, "#9ecae1", "#fdae6b"),
               label="demonstrated pairs (two subtasks, not told apart)")
    for i, (_, pts) in enumerate(sorted(branches.items(), key=lambda kv: -len(kv[1]))):
        px, py = np.array(pts).T
        ax.plot(px, py, "-", lw=2, color=plt.get_cmap("tab10")(i % 10),
                label="ROGER's experts (each where its gate holds >= 10 %)" if i == 0 else None)
    ax.plot(grid, [dpa.predict_one(np.array([g])).mean[0] for g in grid], "k-", lw=2,
            label="one GP on all the data (the paper's DPA)")
    ax.set_xlabel("perception x")
    ax.set_ylabel("action y")
    ax.set_title("One perception, two actions: ROGER's experts hold both branches")
    ax.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()

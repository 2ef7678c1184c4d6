"""``roger experiment peers``'s ``results.json`` and ``learning_curve.png``.

``peers.<policy>``: the start locations' block (success rate with a Wilson 95 % interval,
outcomes, failure modes: :func:`simulator.experiment.report.controller_block`), the ratio to the
HCC, ``held_out`` (the same block from the held-out poses), ``train_cpu_s`` (process CPU
seconds of the training loop, all threads), ``train_wall_s``, ``steps``, ``batch_size``,
``infer_p50_ms`` / ``infer_p99_ms`` (one tick's perception-to-action time on one torch thread,
over every evaluated tick), ``parameters``, ``model_bytes`` (LeRobot's saved policy and
processors), ``incremental: false`` (a new demonstration means training again), the LeRobot
config fields that matter, and the loss at the start and end of training.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["build_results", "write_curve_figure"]

SCHEMA = "roger.experiment.peers/1"
LABELS = {"act": "ACT (LeRobot)", "diffusion": "Diffusion Policy (LeRobot)",
          "roger": "ROGER experts + HCC transitioner", "autonomous": "ROGER + learned "
          "transitions (no HCC)"}


def _ratio(a: float | None, b: float | None) -> float | None:
    return a / b if a is not None and b else None


def peer_block(peer: dict[str, Any], hcc_rate: float | None,
               hcc_held_out: float | None) -> dict[str, Any]:
    """One policy's row (module docstring)."""
    from simulator.experiment.peers_policy import SCALED
    from simulator.experiment.report import controller_block

    t = peer["trained"]
    eps = peer["episodes"]
    block = controller_block(eps["locations"])
    block["ratio_to_hcc"] = _ratio(block["success_rate"], hcc_rate)
    if "held_out" in eps:
        block["held_out"] = controller_block(eps["held_out"])
        block["held_out"]["ratio_to_hcc"] = _ratio(block["held_out"]["success_rate"],
                                                   hcc_held_out)
    losses = np.asarray(t.losses, dtype=np.float64)
    k = max(1, min(100, losses.size // 10))
    block.update({
        "train_cpu_s": t.train_cpu_s, "train_wall_s": t.train_wall_s, "steps": t.steps,
        "batch_size": t.batch_size, "sample_starts": t.samples, "episodes": t.episodes,
        "loss_first": round(float(losses[:k].mean()), 5) if losses.size else None,
        "loss_last": round(float(losses[-k:].mean()), 5) if losses.size else None,
        "infer_p50_ms": peer["infer_p50_ms"], "infer_p99_ms": peer["infer_p99_ms"],
        "ticks_timed": peer["ticks_timed"], "non_finite": peer["non_finite"],
        "parameters": t.parameters(), "model_bytes": peer["model_bytes"],
        "incremental": False, "config": t.config, "changed_from_lerobot_defaults":
        {k: list(v) if isinstance(v, tuple) else v for k, v in SCALED[t.name].items()},
        "episodes_detail": eps,
    })
    return block


def build_results(run: Any, records: list[dict[str, Any]], data: Any, kept: Any,
                  hcc: dict[str, Any], peers: dict[str, Any], curve: dict[str, Any]
                  ) -> dict[str, Any]:
    """``results.json``'s content."""
    import lerobot
    import torch

    from roger_daemon.machine import machine_record
    from simulator.experiment.report import controller_block

    hcc_block = controller_block(hcc["locations"])
    hcc_held = controller_block(hcc["held_out"]) if "held_out" in hcc else None
    hcc_block["episodes_detail"] = hcc
    if hcc_held is not None:
        hcc_block["held_out"] = hcc_held
    plan = run.plan
    return {
        "schema": SCHEMA, "seed": plan.seed, "seeds": plan.seeds,
        "plan": {**plan.to_json(), "frames": run.frames, "batch_size": run.batch_size,
                 "steps": run.steps, "threads": run.threads, "curve": run.curve,
                 "curve_attempts": run.curve_attempts, "start_poses": run.poses_file},
        "demonstrations": {"episodes": len(records), "ticks": len(data),
                           "kept": int(np.asarray(kept).size),
                           "successes": sum(bool(r["success"]) for r in records)},
        "dataset": str(run.out / "dataset"),
        "hcc": hcc_block,
        "peers": {name: peer_block(p, hcc_block["success_rate"],
                                   hcc_held["success_rate"] if hcc_held else None)
                  for name, p in peers.items()},
        "learning_curve": curve,
        "versions": {"lerobot": getattr(lerobot, "__version__", ""),
                     "torch": torch.__version__},
        "machine": machine_record(),
    }


def write_curve_figure(out: Path, curve: dict[str, Any]) -> Path:
    """``OUT/learning_curve.png``: success rate against demonstrations, every learned
    controller (ROGER one pass; each peer retrained per point)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for key, style in (("roger", "o-"), ("autonomous", "s-"), ("act", "^--"),
                       ("diffusion", "v--")):
        rows = curve.get(key) or []
        if rows:
            ax.plot([r["demonstrations"] for r in rows], [r["success_rate"] for r in rows],
                    style, label=LABELS[key])
    ax.set_xlabel("demonstrations (round-robin over the 13 start locations)")
    ax.set_ylabel(f"success rate ({curve.get('attempts', 1)} attempt(s) per location)")
    ax.set_ylim(-0.03, 1.03)
    ax.set_xscale("log")
    ticks = curve.get("demonstrations") or []
    ax.set_xticks(ticks, [str(t) for t in ticks])
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    path = out / "learning_curve.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

"""The demonstrations of ``roger experiment peers``: goal-scoring's stream, as a LeRobot dataset.

* :func:`demonstrations`: the HCC's demonstrations of ``roger experiment goal-scoring`` with
  the same plan (same seeds, start locations, shots, episode limit, vision) and the indices its
  downsampling keeps (:func:`simulator.experiment.pipeline.downsample_indices`);
* :func:`export_stream`: every demonstrated tick, one episode per demonstration, through
  ROGER's LeRobot v3 export (:func:`roger_daemon.datasets.write_dataset`, float32, LeRobot's
  usual dtype for float32 weights). The downsampled points are the frames a training sample
  starts at; ACT's and Diffusion Policy's action chunks are the demonstrator's following
  ticks, which only the whole stream holds (docs/peers.md, "Data");
* :func:`curve_order` / :func:`curve_episodes`: the learning curve's demonstration order,
  round-robin over the start locations (shot 0 of every location, then shot 1, ...), so that
  the first 10 demonstrations cover 10 locations rather than one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from simulator.experiment.training import Demonstrations

__all__ = ["curve_episodes", "curve_order", "demonstrations", "episode_of", "export_stream",
           "to_pairs"]

IntArray = npt.NDArray[np.int64]


def demonstrations(plan: Any) -> tuple[Demonstrations, list[dict[str, Any]], IntArray]:
    """The goal-scoring plan's demonstrations (every tick), their records and the kept
    (downsampled) indices."""
    from simulator.experiment import pipeline as pl

    data, records = pl.demonstrate(plan)
    return data, [r.to_json() for r in records], pl.downsample_indices(data, plan)


def episode_of(data: Demonstrations) -> IntArray:
    """Each tick's demonstration number 0, 1, ... (a demonstration starts at tick 0)."""
    return (np.cumsum(data.tick == 0) - 1).astype(np.int64)


def to_pairs(data: Demonstrations) -> Any:
    """The demonstrations as :class:`roger_daemon.datasets.Pairs` (AIBO profile, the
    simulator's 30 Hz, every action the teacher's)."""
    from roger_daemon.datasets import Pairs
    from roger_daemon.profiles import load_profile

    profile = load_profile("aibo")
    return Pairs(x=np.asarray(data.x, dtype=np.float64), y=np.asarray(data.y, dtype=np.float64),
                 tick=np.asarray(data.tick, dtype=np.int64), episode=episode_of(data),
                 label=list(data.labels), source=["teacher"] * len(data), profile=profile,
                 fps=profile.rate_hz, robot="aibo", task=profile.task,
                 meta={"source_log": "roger experiment peers"})


def export_stream(data: Demonstrations, root: Path) -> list[Path]:
    """Write the demonstrations as a LeRobot v3 dataset in ``root`` (float32)."""
    from roger_daemon.datasets import write_dataset

    return write_dataset(to_pairs(data), "lerobot", root, "demonstrations", dtype="float32")


def curve_order(records: list[dict[str, Any]]) -> list[int]:
    """Demonstration numbers in the learning curve's order: by shot, then by location."""
    return sorted(range(len(records)),
                  key=lambda i: (records[i]["repetition"], records[i]["location"], i))


def curve_episodes(records: list[dict[str, Any]], n: int) -> list[int]:
    """The first ``n`` demonstrations in :func:`curve_order`, as sorted episode numbers."""
    return sorted(curve_order(records)[:n])


def curve_stream(data: Demonstrations, kept: IntArray, records: list[dict[str, Any]]
                 ) -> tuple[Demonstrations, IntArray]:
    """The kept points in the curve's order (demonstration by demonstration, in
    :func:`curve_order`; ticks in order) and, per point, its demonstration's rank in that
    order (ROGER's one pass: the model after the first ``n`` demonstrations has learned the
    points of rank < n)."""
    episode = episode_of(data)
    rank = np.empty(len(records), dtype=np.int64)
    rank[np.asarray(curve_order(records), dtype=np.int64)] = np.arange(len(records))
    order = kept[np.lexsort((kept, rank[episode[kept]]))]
    return data.subset(order), rank[episode[order]]

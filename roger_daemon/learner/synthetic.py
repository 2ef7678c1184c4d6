"""Deterministic synthetic demonstration streams (benchmark and tests; generated, not stored).

:func:`subtask_stream` imitates the paper's data (section IV): a demonstrator cycles through
subtasks; within a segment a latent state (think robot/ball/goal geometry, 3-D) moves smoothly;
the perception ``x`` (23-D) is a smooth nonlinear image of the latent state, and the action
``y`` (9-D) a smooth function of it that depends on the subtask.  Subtasks 2 and 3 live in the
same latent region, so identical inputs map to different outputs (a multimap, like "aim" vs
"seek" in the paper); subtasks 0 and 1 overlap partly.  Labels are for evaluation only.

:func:`sqrt_multimap` is the two-branch toy ``y = +sqrt(x)`` / ``y = -sqrt(x)``, interleaved.

Everything is generated from a fixed seed with numpy's PCG64, so a stream is the same on every
run (up to the last bit of ``sin``/``tanh`` on a different platform).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["BENCH_SEED", "Stream", "sqrt_multimap", "subtask_stream"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

BENCH_SEED = 20100618  # fixed: the benchmark stream is part of the package
BENCH_D_X = 23  # the benchmark stream's perception dimension (the AIBO's)


@dataclass(frozen=True)
class Stream:
    """A demonstration stream: inputs (N, d_x), outputs (N, d_y), subtask labels (N,)."""

    x: FloatArray
    y: FloatArray
    labels: IntArray

    def __len__(self) -> int:
        return int(self.labels.size)


def subtask_stream(n_points: int = 4000, d_x: int = BENCH_D_X, d_y: int = 9, n_subtasks: int = 4,
                   seed: int = BENCH_SEED, latent_dim: int = 3) -> Stream:
    """The benchmark stream: ``n_points`` pairs, equal shares per subtask, segments in cycle.

    Modelled on the AIBO perception of the paper: the first ``3 * n_objects`` inputs are
    (x, y, size) of coloured objects, the rest proprioception.  Each subtask sees a subset of
    the objects (subtask 0 the even ones, subtask 1 the odd ones; an invisible object reads
    ``(-1, -1, -1)``), so gates can tell most subtasks apart by their inputs.  Subtask 2
    has the same visibility and latent region as subtask 0 (identical inputs, different
    actions: the paper's aim/seek multimap) and subtask 3 shares subtask 1's visibility with a
    half-overlapping region.  Segments of 25-75 steps visit the
    subtasks in the order 0, 1, 2, ...; within a segment the latent state random-walks
    (smoothed velocity, reflected at its box).  The last output is a discrete action indicator.
    """
    if n_points < 1 or n_subtasks < 1 or d_x < 1 or d_y < 1:
        raise ValueError("n_points, n_subtasks, d_x and d_y must be >= 1")
    rng = np.random.default_rng(seed)
    w = rng.normal(0.0, 1.0, (d_x, latent_dim))
    b = rng.uniform(-np.pi, np.pi, d_x)
    v = rng.normal(0.0, 1.5, (n_subtasks, d_y, latent_dim))
    c = rng.uniform(-np.pi, np.pi, (n_subtasks, d_y))
    indicator = rng.integers(-1, 2, n_subtasks).astype(np.float64)
    centres = rng.uniform(-1.0, 1.0, (n_subtasks, latent_dim))
    n_objects = min(6, d_x // 3)
    visible = rng.uniform(size=(n_subtasks, n_objects)) < 0.5
    visible[: min(2, n_subtasks)] = np.arange(n_objects) % 2 == np.arange(2)[: n_subtasks, None]
    if n_subtasks >= 3:  # subtask 2 = subtask 0's inputs (full overlap)
        centres[2] = centres[0]
        visible[2] = visible[0]
        indicator[2] = indicator[0] - 1.0 if indicator[0] > -1 else 1.0
    if n_subtasks >= 4:  # subtask 3 = subtask 1's visibility, region half-overlapping
        centres[3] = centres[1] + 0.5
        visible[3] = visible[1]
    half = 0.5
    quota = np.full(n_subtasks, n_points // n_subtasks)
    quota[: n_points % n_subtasks] += 1
    zs, labels = [], []
    k = 0
    while quota.sum() > 0:
        if quota[k] > 0:
            length = int(min(quota[k], rng.integers(25, 76)))
            lo, hi = centres[k] - half, centres[k] + half
            z = rng.uniform(lo, hi)
            vel = rng.normal(0.0, 0.01, latent_dim)
            for _ in range(length):
                vel = 0.9 * vel + rng.normal(0.0, 0.004, latent_dim)
                z = z + vel
                over = (z < lo) | (z > hi)
                vel[over] = -vel[over]
                z = np.clip(z, lo, hi)
                zs.append(z)
                labels.append(k)
            quota[k] -= length
        k = (k + 1) % n_subtasks
    zarr = np.asarray(zs)
    lab = np.asarray(labels, dtype=np.int64)
    x = 0.5 * np.sin(zarr @ w.T + b)
    hidden = np.repeat(~visible[lab], 3, axis=1)  # (N, 3 * n_objects)
    blank = np.full(3 * n_objects, -1.0)
    obj = x[:, : 3 * n_objects]
    obj[hidden] = np.broadcast_to(blank, obj.shape)[hidden]
    x = x + rng.normal(0.0, 0.002, x.shape)
    y = 0.5 * np.sin(np.einsum("noi,ni->no", v[lab], zarr) + c[lab])
    y[:, -1] = indicator[lab]
    y = y + rng.normal(0.0, 0.01, y.shape)
    return Stream(x=x, y=y, labels=lab)


def sqrt_multimap(n_points: int = 400, seed: int = 0, noise: float = 0.02) -> Stream:
    """``x ~ U(0, 1)``; even steps ``y = +sqrt(x)`` (label 0), odd steps ``y = -sqrt(x)``."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, n_points)
    lab = (np.arange(n_points) % 2).astype(np.int64)
    y = np.where(lab == 0, 1.0, -1.0) * np.sqrt(x) + rng.normal(0.0, noise, n_points)
    return Stream(x=x[:, None], y=y[:, None], labels=lab)

"""The surface patches of :class:`~simulator.vision.FastVision`: boxes, cylinder and disc samples.

A patch set is ``(points, normals, areas, owner instances, ray extents)``, one per patch
(docs/aibo-simulation.md §5.2); every float is computed with the same operations in the same
order as before these helpers left ``simulator/vision.py``, so the blobs are bit-identical.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CYL_OFFS", "DISC", "UP", "Patches", "box_patches", "concat_patches", "cross3",
           "no_patches"]

DISC = np.array(
    [(0.0, 0.0)] + [(0.68 * math.cos(a), 0.68 * math.sin(a)) for a in np.arange(6) * math.pi / 3]
)  # 7 equal-area-ish samples of the unit disc


def box_patches(
    centre: tuple[float, float, float], half: tuple[float, float, float], spacing: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patch centres, outward normals and areas on the four vertical faces of a box."""
    pts, nrm, area = [], [], []
    c = np.asarray(centre)
    hx, hy, hz = half
    for axis, other, h_n, h_o in ((0, 1, hx, hy), (1, 0, hy, hx)):
        for sign in (-1.0, 1.0):
            n_o = max(1, round(2 * h_o / spacing))
            n_z = max(1, round(2 * hz / spacing))
            for i in range(n_o):
                for j in range(n_z):
                    q = c.copy()
                    q[axis] += sign * h_n
                    q[other] += -h_o + (i + 0.5) * 2 * h_o / n_o
                    q[2] += -hz + (j + 0.5) * 2 * hz / n_z
                    n = np.zeros(3)
                    n[axis] = sign
                    pts.append(q)
                    nrm.append(n)
                    area.append((2 * h_o / n_o) * (2 * hz / n_z))
    return np.array(pts), np.array(nrm), np.array(area)


def cross3(a: tuple[float, ...], b: tuple[float, ...]) -> np.ndarray:
    """``np.cross`` of two 3-vectors with the same operations in the same order (bit-equal)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


UP = (0.0, 0.0, 1.0)
CYL_OFFS = [(s, t) for s in (-2 / 3, 0.0, 2 / 3) for t in (-0.5, 0.5)]

Patches = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def no_patches() -> Patches:
    """An empty patch set."""
    z3 = np.zeros((0, 3))
    z1 = np.zeros(0)
    return z3, z3, z1, z1.astype(np.int64), z1


def concat_patches(parts: list[Patches]) -> Patches:
    """Row-wise concatenation of patch sets (owner as int64)."""
    if not parts:
        return no_patches()
    pts, nrm, area, owner, ext = (np.concatenate(c) for c in zip(*parts, strict=True))
    return pts, nrm, area, owner.astype(np.int64), ext

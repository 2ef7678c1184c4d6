"""3-D vector algebra with a fixed order of IEEE operations, identical on every machine.

``numpy``'s ``@``, ``dot`` and ``linalg.norm`` of float64 arrays call BLAS, whose kernels
(chosen at run time for the CPU: Haswell, SkylakeX, Zen, ...) sum in different orders and
with or without fused multiply-adds, so the last bit of a 3-vector product depends on the
machine. The simulator is chaotic (contacts, thresholds in the controller): one bit in a
camera ray flips a blob's pixel a few hundred ticks later, and the demonstrations, and
everything learned from them, differ between two CPUs (measured: 17 of 130 demonstrations of
the goal-scoring experiment changed length between the Haswell and SkylakeX kernels of the
same OpenBLAS). These helpers write each product out as separate multiplies and adds, which
IEEE 754 rounds the same way everywhere (docs/reproducibility.md).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

__all__ = ["dot3", "matmul3", "matvec3", "norm3", "rows_dot3"]

FloatArray = npt.NDArray[np.float64]


def dot3(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """``a · b`` of two 3-vectors, as ``a0 b0 + a1 b1 + a2 b2`` left to right.

    >>> dot3([1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    32.0
    """
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    return float(x[0]) * float(y[0]) + float(x[1]) * float(y[1]) + float(x[2]) * float(y[2])


def norm3(a: npt.ArrayLike) -> float:
    """Euclidean length of a 3-vector (``sqrt(dot3(a, a))``).

    >>> norm3([3.0, 4.0, 12.0])
    13.0
    """
    return math.sqrt(dot3(a, a))


def rows_dot3(rows: FloatArray, v: npt.ArrayLike) -> FloatArray:
    """``rows @ v`` for ``rows`` of shape ``(n, 3)``: one dot product per row, same order.

    >>> rows_dot3(np.array([[1.0, 0.0, 0.0], [1.0, 2.0, 3.0]]), [2.0, 1.0, 1.0])
    array([2., 7.])
    """
    w = np.asarray(v, dtype=np.float64)
    out: FloatArray = rows[:, 0] * w[0] + rows[:, 1] * w[1] + rows[:, 2] * w[2]
    return out


def matvec3(m: FloatArray, v: npt.ArrayLike) -> FloatArray:
    """``m @ v`` for a 3x3 matrix and a 3-vector.

    >>> matvec3(np.eye(3) * 2.0, [1.0, 2.0, 3.0])
    array([2., 4., 6.])
    """
    return np.array([dot3(m[i], v) for i in range(3)])


def matmul3(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` for two 3x3 matrices.

    >>> matmul3(np.eye(3), np.arange(9.0).reshape(3, 3))[2]
    array([6., 7., 8.])
    """
    bt = np.ascontiguousarray(b.T)
    return np.array([[dot3(a[i], bt[j]) for j in range(3)] for i in range(3)])

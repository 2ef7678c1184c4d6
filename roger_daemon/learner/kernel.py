"""The RBF kernel shared by every expert (docs/learner-math.md §2.3, fidelity switch 1).

``k(a, b) = exp(-|a - b|^2 / (2 * theta_w^2 * s))`` with ``s = 1`` (textbook) or ``s = d_x``
(Grollman's SOGP library divides the squared distance by the input dimension).  The amplitude
is 1, so ``k* = k(x, x) = 1`` for every ``x``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["RBFKernel"]

FloatArray = npt.NDArray[np.float64]


class RBFKernel:
    """Isotropic squared-exponential kernel with unit amplitude.

    Parameters
    ----------
    width : float
        ``theta_w``.
    d_x : int
        Input dimension (used only by the ``"grollman"`` scaling).
    dim_scaling : {"textbook", "grollman"}
        Whether the squared distance is also divided by ``d_x``.

    Examples
    --------
    >>> k = RBFKernel(0.5, d_x=2)
    >>> float(k(np.zeros((1, 2)), np.array([0.5, 0.0]))[0])  # exp(-0.25 / 0.5)
    0.6065306597126334
    """

    k_star = 1.0  # k(x, x): amplitude 1

    def __init__(self, width: float, d_x: int, dim_scaling: str = "textbook") -> None:
        self.width = float(width)
        self.d_x = int(d_x)
        self.dim_scaling = dim_scaling
        scale = float(d_x) if dim_scaling == "grollman" else 1.0
        # exp(-gamma * |a - b|^2), gamma = 1 / (2 w^2 s)
        self.gamma = 1.0 / (2.0 * self.width**2 * scale)
        self._ones_cache: FloatArray = np.ones(self.d_x)

    def __call__(self, basis: FloatArray, x: FloatArray) -> FloatArray:
        """Kernel vector ``[k(b_1, x), ..., k(b_n, x)]`` for rows ``b_i`` of ``basis`` (n, d_x).

        Differences are formed explicitly (not via ``|b|^2 - 2 b.x + |x|^2``) so that ``k`` is
        accurate near 1, where the novelty residual ``gamma = k* - k^T Q k`` is decided.
        """
        diff = basis - x
        if diff.ndim != 2:
            batched: FloatArray = np.exp(-self.gamma * np.einsum("...ij,...ij->...i", diff, diff))
            return batched
        np.square(diff, out=diff)
        out: FloatArray = diff @ self._ones(diff.shape[1])  # row sums by BLAS gemv
        out *= -self.gamma
        return np.exp(out, out=out)

    def _ones(self, d: int) -> FloatArray:
        ones = self._ones_cache
        if ones.shape[0] != d:
            ones = self._ones_cache = np.ones(d)
        return ones

    def gram(self, a: FloatArray, b: FloatArray) -> FloatArray:
        """Kernel matrix ``K[i, j] = k(a_i, b_j)`` for (n, d_x) and (m, d_x) inputs."""
        diff = a[:, None, :] - b[None, :, :]
        gram: FloatArray = np.exp(-self.gamma * np.einsum("ijk,ijk->ij", diff, diff))
        return gram

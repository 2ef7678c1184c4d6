"""Kernel width from the data: the GP evidence on a window of points (issue 13, lever e).

The paper found the GP parameters the most sensitive and left adapting them to future work
(section III.C).  This is the offline half of that: :func:`select_width` scores a grid of
widths by the exact log marginal likelihood (evidence) of one GP on a window of consecutive
points and returns the best, to be used as ``theta_w``.  It is not an online option of the
model (changing the kernel of a running SOGP would invalidate ``Q`` and ``C``).

Use a *short* window of consecutive demonstration points: temporally extended subtasks make a
short window mostly one subtask, whereas a single GP on a whole multimap explains the
branches' disagreement as noise and prefers widths that are too broad.  Inputs and outputs in
the model's units (scaled, weighted: ``AffineScaling.x_in``/``y_in``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.linalg import cho_factor, cho_solve

from roger_daemon.learner.kernel import RBFKernel

__all__ = ["log_evidence", "select_width"]

FloatArray = npt.NDArray[np.float64]


def log_evidence(x: FloatArray, y: FloatArray, width: float, noise: float, *,
                 dim_scaling: str = "textbook", prior_mean: FloatArray | None = None) -> float:
    """``log p(Y | X)`` of independent GP outputs with kernel width ``width`` and noise ``noise``.

    ``sum_j log N(Y[:, j]; m_j 1, K + noise I)``; ``prior_mean`` is ``m`` (zeros by default,
    e.g. ``Y.mean(0)`` for ``gp_prior_mean = "expert"``).

    >>> x = np.linspace(0, 1, 5)[:, None]
    >>> round(log_evidence(x, np.sin(3 * x), 0.5, 0.01), 3)
    -1.932
    """
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    y = np.asarray(y, dtype=np.float64).reshape(x.shape[0], -1)
    n, d_y = y.shape
    gram = RBFKernel(width, x.shape[1], dim_scaling).gram(x, x) + noise * np.eye(n)
    factor = cho_factor(gram, lower=True)
    resid = y if prior_mean is None else y - np.asarray(prior_mean, dtype=np.float64)
    fit = float(np.sum(resid * cho_solve(factor, resid)))
    logdet = 2.0 * float(np.sum(np.log(np.diagonal(factor[0]))))
    return -0.5 * fit - 0.5 * d_y * logdet - 0.5 * n * d_y * math.log(2.0 * math.pi)


def select_width(x: FloatArray, y: FloatArray, widths: Sequence[float], noise: float, *,
                 window: int | None = None, dim_scaling: str = "textbook",
                 center: bool = False) -> tuple[float, FloatArray]:
    """``(best width, log evidence of every width)`` on the last ``window`` points.

    ``center=True`` uses the window's mean output as the GP prior mean (as
    ``gp_prior_mean = "expert"`` does for an expert).
    """
    if not widths:
        raise ValueError("widths must be a non-empty sequence of floats > 0")
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    y = np.asarray(y, dtype=np.float64).reshape(x.shape[0], -1)
    if window is not None:
        x, y = x[-window:], y[-window:]
    mean = y.mean(axis=0) if center else None
    scores = np.array([log_evidence(x, y, float(w), noise, dim_scaling=dim_scaling,
                                    prior_mean=mean) for w in widths])
    return float(widths[int(np.argmax(scores))]), scores

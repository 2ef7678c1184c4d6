"""Scalar formulas written once in plain Python: called as they are by the Python code, and
compiled by numba into the kernels that use them (:mod:`.jit_particles`).

This module imports no numba (the learner's Python code uses it before any kernel loads); its
name puts it among the kernel modules whose sources fingerprint numba's cache
(:mod:`.jit_compile`).  Compiled, ``math.lgamma`` is not CPython's own implementation, so the
two runs of a formula agree to round-off, not bit for bit (tested, tests/learner/test_gate.py).
"""

from __future__ import annotations

import math

__all__ = ["student_t_normaliser"]


def student_t_normaliser(kappa: float, nu: float, logdet_lam: float, d: int
                         ) -> tuple[float, float, float]:
    """``(log normaliser, (nu_t + d)/2, 1/(nu_t c))`` of a NIW gate's Student-t predictive
    (docs/learner-math.md §3.3), from its ``kappa``, ``nu`` and ``log|Lambda|``.

    ``log t(x) = lognorm - (nu_t + d)/2 * log(1 + delta / nu_t)`` with ``nu_t = nu - d + 1``,
    ``delta = (x - mu)^T Lambda^{-1} (x - mu) / c``, ``Sigma_t = c Lambda`` and
    ``c = (kappa + 1) / (kappa nu_t)``.
    """
    nu_t = nu - d + 1.0
    c = (kappa + 1.0) / (kappa * nu_t)
    logdet_sigma = d * math.log(c) + logdet_lam
    lognorm = (math.lgamma((nu_t + d) / 2.0) - math.lgamma(nu_t / 2.0)
               - 0.5 * d * math.log(nu_t * math.pi) - 0.5 * logdet_sigma)
    return lognorm, 0.5 * (nu_t + d), 1.0 / (nu_t * c)

"""A fixed-size window of recent samples with percentiles (latencies, periods, durations)."""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["Window"]


class Window:
    """The last ``size`` float samples; :meth:`pct` is a percentile of them (0 when empty)."""

    def __init__(self, size: int = 1000) -> None:
        self.values: deque[float] = deque(maxlen=size)

    def add(self, v: float) -> None:
        """Add one sample (the oldest falls out when the window is full)."""
        self.values.append(v)

    def pct(self, q: float) -> float:
        """The ``q``-th percentile of the samples (0.0 when there are none)."""
        if not self.values:
            return 0.0
        return float(np.percentile(np.fromiter(self.values, float), q))

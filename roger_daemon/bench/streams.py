"""The pair streams ``roger bench fleet`` and ``roger bench soak`` feed to the daemon.

``aibo``: the 1,500 recorded AIBO demonstration pairs shipped for ``roger bench learner
--stream aibo`` (``data/aibo-demonstrations.npz``), the realistic workload of the daemon's
default configuration (the AIBO profile): ``beta`` and the experts the data supports bound
the model.  ``synthetic``: the synthetic subtask stream, whose inputs lie outside the AIBO
profile's ranges, so the default configuration keeps opening experts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protocols.aibo import SUBTASKS
from roger_daemon.learner.synthetic import subtask_stream

__all__ = ["FLEET_STREAMS", "FeedStream", "feed_stream"]

FLEET_STREAMS = ("aibo", "synthetic")
_AIBO = Path(__file__).with_name("data") / "aibo-demonstrations.npz"


@dataclass(frozen=True)
class FeedStream:
    """Pairs fed to the daemon, cycled: inputs, outputs and each pair's subtask label."""

    x: np.ndarray
    y: np.ndarray
    labels: tuple[str, ...]


def feed_stream(name: str, points: int = 4000) -> FeedStream:
    """``aibo``: the recorded AIBO demonstrations (1,500 pairs); ``synthetic``: ``points``
    pairs of the synthetic subtask stream."""
    if name == "aibo":
        with np.load(_AIBO) as data:
            names = [str(v) for v in data["label_names"]]
            return FeedStream(data["x"], data["y"],
                              tuple(names[int(i)] for i in data["labels"]))
    if name != "synthetic":
        raise ValueError(f"unknown stream {name!r}; choose from {FLEET_STREAMS}")
    st = subtask_stream(points)
    return FeedStream(st.x, st.y, tuple(SUBTASKS[int(i) % len(SUBTASKS)] for i in st.labels))

"""The AIBO's memory layout for the learned transitions (``protocols/AIBO.md``).

The blobs the memories track are the ball and the two goals; the head's tilt and pan are used
as they are (scaled by their documented ranges); odometry integrates the walk's turn command;
the action indicator (kick +1, trap -1) starts the two timed motions.
"""

from __future__ import annotations

import math

from protocols.aibo import (
    ACTION_NAMES,
    INDICATOR_THRESHOLD,
    PERCEPTION_NAMES,
    PERCEPTION_RANGES,
    blob_slice,
)
from roger_daemon.fsm.memory import MemorySpec
from roger_daemon.learner.params import range_scaling

__all__ = ["AIBO_HALF_FOV", "aibo_memory"]

#: Half the head camera's horizontal field of view (56.9 degrees, ``protocols/AIBO.md``).
AIBO_HALF_FOV = math.radians(56.9) / 2.0


def aibo_memory(hz: float = 30.0) -> MemorySpec:
    """The AIBO's :class:`MemorySpec`: ball and goals tracked, head tilt and pan as inputs."""
    offset, scale = range_scaling(PERCEPTION_RANGES)
    proprio = tuple((i, offset[i], scale[i]) for i in (PERCEPTION_NAMES.index("head_tilt"),
                                                       PERCEPTION_NAMES.index("head_pan")))
    return MemorySpec(
        blobs=tuple((c, int(blob_slice(c).start)) for c in ("ball", "yellow_goal", "blue_goal")),
        proprio=proprio, pan=PERCEPTION_NAMES.index("head_pan"), half_fov=AIBO_HALF_FOV,
        turn=ACTION_NAMES.index("walk_turn"), indicator=ACTION_NAMES.index("action"),
        threshold=INDICATOR_THRESHOLD, hz=hz)

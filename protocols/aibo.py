"""The AIBO task's vector layouts (paper section IV): 23-D perception, 9-D action.

Index names, the "not seen" encoding and the action-indicator encoding. Units, ranges and
conventions are documented in ``protocols/AIBO.md`` and implemented by ``simulator/``. The
daemon's robot profile ``configs/robots/aibo.toml`` holds the same names and ranges as data
(``roger_daemon.profiles``; a test checks that the two agree bit for bit).
"""

from __future__ import annotations

import math

from protocols.messages import Dims

__all__ = [
    "ACTION_NAMES",
    "ACTION_RANGES",
    "COLOURS",
    "DIMS",
    "INDICATOR",
    "INDICATOR_THRESHOLD",
    "NOT_SEEN",
    "PERCEPTION_NAMES",
    "PERCEPTION_RANGES",
    "STATE_FREE_DIMS",
    "SUBTASKS",
    "blob_slice",
    "decode_indicator",
    "encode_indicator",
    "is_seen",
]

#: The six colour classes the vision reports, in vector order.
COLOURS = ("ball", "yellow_goal", "blue_goal", "pink", "yellow_beacon", "blue_beacon")

#: 6 colours x (image x, image y, size) + head (tilt, pan, nod) + tail (pan, tilt) = 23.
PERCEPTION_NAMES = tuple(f"{c}_{a}" for c in COLOURS for a in ("x", "y", "size")) + (
    "head_tilt",
    "head_pan",
    "head_nod",
    "tail_pan",
    "tail_tilt",
)

#: walk (forward, left, turn) + head targets (tilt, pan, nod) + tail targets (pan, tilt)
#: + the action indicator (kick / trap / none) = 9.
ACTION_NAMES = (
    "walk_forward",
    "walk_left",
    "walk_turn",
    "head_tilt",
    "head_pan",
    "head_nod",
    "tail_pan",
    "tail_tilt",
    "action",
)

#: The hand-coded controller's subtasks (paper Fig. 5/6a), the labels carried by actions.
SUBTASKS = ("seek", "trap", "aim", "kick")

DIMS = Dims(x=len(PERCEPTION_NAMES), y=len(ACTION_NAMES))
assert DIMS == Dims(23, 9)

#: (x, y, size) of a colour class that is not seen. A seen blob always has size > 0
#: (at least the minimum pixel count), so ``size < 0`` is unambiguous.
NOT_SEEN = (0.0, 0.0, -1.0)

_BLOB_Y = 160.0 / 208.0  # |blob y| <= H/W at the default 208x160 camera
_BLOB = ((-1.0, 1.0), (-_BLOB_Y, _BLOB_Y), (-1.0, 1.0))  # x, y, size (-1 = not seen)
_HEAD = ((math.radians(-75.0), 0.0), (math.radians(-88.0), math.radians(88.0)),
         (math.radians(-15.0), math.radians(45.0)))  # tilt, pan, nod
_TAIL = ((math.radians(-45.0), math.radians(45.0)), (math.radians(5.0), math.radians(60.0)))

#: Documented range ``(low, high)`` of every perception entry (``protocols/AIBO.md``).
PERCEPTION_RANGES: tuple[tuple[float, float], ...] = _BLOB * len(COLOURS) + _HEAD + _TAIL

#: Documented range of every action entry: walk clips, head/tail joint ranges, indicator.
ACTION_RANGES: tuple[tuple[float, float], ...] = (
    (-0.18, 0.225), (-0.17, 0.17), (-2.1, 2.1), *_HEAD, *_TAIL, (-1.0, 1.0))

#: Perception entries that carry no task state: the tail pan wags on a clock and the tail
#: tilt is constant (``simulator/controllers/hcc.py``), so the learner's default AIBO profile
#: drops them.
STATE_FREE_DIMS = (PERCEPTION_NAMES.index("tail_pan"), PERCEPTION_NAMES.index("tail_tilt"))

assert len(PERCEPTION_RANGES) == DIMS.x and len(ACTION_RANGES) == DIMS.y


#: Action indicator values (``y[8]``): what the controller emits.
INDICATOR = {"none": 0.0, "kick": 1.0, "trap": -1.0}

#: ``y[8] >= +threshold`` means kick, ``y[8] <= -threshold`` trap, anything between none.
INDICATOR_THRESHOLD = 0.5


def blob_slice(colour: str) -> slice:
    """The slice of the perception vector holding ``colour``'s (x, y, size)."""
    i = COLOURS.index(colour)
    return slice(3 * i, 3 * i + 3)


def is_seen(size: float) -> bool:
    """Whether a blob's size entry means "seen"."""
    return size > 0.0


def encode_indicator(name: str) -> float:
    """The ``y[8]`` value for ``"none"``, ``"kick"`` or ``"trap"``."""
    return INDICATOR[name]


def decode_indicator(value: float) -> str:
    """``"kick"``, ``"trap"`` or ``"none"`` for a (possibly regressed) ``y[8]``; NaN is none."""
    if not math.isfinite(value):
        return "none"
    if value >= INDICATOR_THRESHOLD:
        return "kick"
    if value <= -INDICATOR_THRESHOLD:
        return "trap"
    return "none"

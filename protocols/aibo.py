"""The AIBO task's vector layouts (paper section IV): 23-D perception, 9-D action.

Index names only; units, ranges and the "not seen" encoding are documented in
``protocols/README.md`` (section "AIBO vectors") and implemented by ``simulator/``.
"""

from __future__ import annotations

from protocols.messages import Dims

__all__ = ["ACTION_NAMES", "COLOURS", "DIMS", "PERCEPTION_NAMES", "SUBTASKS"]

#: The six colour classes the vision reports, in vector order.
COLOURS = ("ball", "yellow_goal", "blue_goal", "pink", "yellow_beacon", "blue_beacon")

#: 6 colours x (image x, image y, size) + head (tilt, pan, nod) + tail (pan, tilt) = 23.
PERCEPTION_NAMES = tuple(
    f"{c}_{a}" for c in COLOURS for a in ("x", "y", "size")
) + ("head_tilt", "head_pan", "head_nod", "tail_pan", "tail_tilt")

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

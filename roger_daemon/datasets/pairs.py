"""A session's training pairs as arrays, with episodes, labels and sources: what datasets hold.

:func:`pairs_from_log` reads a session log with the replay reader
(:func:`roger_daemon.recording.session_read.read_timeline`: the daemon's decision records of a
version-2 log, the re-paired inputs of a version-1 log), so a dataset holds exactly the pairs
the daemon learned, in learning order. Around them it reads:

* **episodes**: the simulator's (or robot's) ``episode`` messages; a pair belongs to the
  newest ``start`` at or before its tick, and a model reset starts a new episode too. A log
  without episode messages is one episode per model segment. Episodes are numbered 0, 1, ...
  over those that hold pairs (LeRobot wants them contiguous);
* **labels**: the subtask label the action carried (data for evaluation; never learned);
* **sources**: who gave the action, ``"teacher"`` or ``"robot"``, where the log says (the
  ``source`` of the ``learned`` record, else of the action message; ``""`` otherwise);
* the robot **profile** (names) and the **fps** (the daemon's ``rate_hz``, else the profile's).

:class:`Pairs` is the one in-memory form every dataset format writes and reads.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt

from protocols import keys
from roger_daemon.profiles import RobotProfile

__all__ = ["Pairs", "pairs_from_log"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass
class Pairs:
    """Training pairs in learning order (row ``i`` of every array is pair ``i``)."""

    x: FloatArray  # (N, d_x) perceptions
    y: FloatArray  # (N, d_y) actions
    tick: IntArray  # (N,) the tick each pair was sent with
    episode: IntArray  # (N,) episode number, 0 .. E-1, non-decreasing
    label: list[str]  # (N,) subtask labels ("" if none)
    source: list[str]  # (N,) "teacher" / "robot" / ""
    profile: RobotProfile
    fps: float = 30.0
    robot: str = "robot"
    task: str = ""
    #: what a session log needs to rebuild the same model: learner_params (JSON text),
    #: seed, model, and where the pairs came from (session_id, source file)
    meta: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.tick)
        if self.x.shape != (n, self.profile.dims.x) or self.y.shape != (n, self.profile.dims.y):
            raise ValueError(f"pairs: x {self.x.shape} and y {self.y.shape} do not match "
                             f"{n} ticks of a {self.profile.dims.x}-D -> "
                             f"{self.profile.dims.y}-D robot")
        if len(self.episode) != n or len(self.label) != n or len(self.source) != n:
            raise ValueError("pairs: episode, label and source need one entry per pair")
        if n and (self.episode[0] != 0 or np.any(np.diff(self.episode) < 0)
                  or np.any(np.diff(self.episode) > 1)):
            raise ValueError("pairs: episodes must be numbered 0, 1, ... in order")
        if not self.fps > 0:
            raise ValueError(f"pairs: fps must be > 0, got {self.fps!r}")

    def __len__(self) -> int:
        return int(self.tick.size)

    @property
    def episodes(self) -> int:
        """The number of episodes."""
        return int(self.episode[-1]) + 1 if len(self) else 0

    def frame_index(self) -> IntArray:
        """Each pair's index within its episode (0, 1, ...)."""
        out = np.zeros(len(self), dtype=np.int64)
        if len(self):
            starts = np.flatnonzero(np.diff(self.episode, prepend=-1))
            for a, b in zip(starts, [*starts[1:], len(self)], strict=True):
                out[a:b] = np.arange(b - a)
        return out

    def same_pairs(self, other: Pairs) -> bool:
        """The same pairs bit for bit: x, y, ticks, episodes, labels and sources."""
        return (np.array_equal(self.x, other.x) and np.array_equal(self.y, other.y)
                and np.array_equal(self.tick, other.tick)
                and np.array_equal(self.episode, other.episode)
                and self.label == other.label and self.source == other.source)


def _raw(payload: bytes) -> Mapping[str, Any]:
    try:
        value = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception:
        return {}
    return value if isinstance(value, dict) else {}


@dataclass
class _Around:
    """What one pass over a log finds besides the pairs."""

    starts: list[tuple[int, int]] = field(default_factory=list)  # (tick, episode) of "start"
    learned_source: dict[int, str] = field(default_factory=dict)  # pair index -> source
    action_source: dict[int, str] = field(default_factory=dict)  # tick -> source


def _around(paths: list[Path], robot: str) -> _Around:
    from roger_daemon.recording.mcapio import LogReader

    out = _Around()
    episode_key, action_key = keys.episode(robot), keys.action(robot)
    learned_key = keys.decision(robot, "learned")
    for path in paths:
        for lm in LogReader(path).messages():
            if lm.topic not in (episode_key, action_key, learned_key):
                continue
            m = _raw(lm.message.data)
            tick = m.get("tick")
            if not isinstance(tick, int):
                continue
            source = m.get("source")
            if lm.topic == episode_key and m.get("event") == "start":
                out.starts.append((tick, int(m.get("episode", len(out.starts)))))
            elif lm.topic == action_key and isinstance(source, str) and source:
                out.action_source[tick] = source
            elif lm.topic == learned_key and isinstance(source, str) and source:
                updates = m.get("updates")
                if isinstance(updates, int):
                    out.learned_source[updates - 1] = source
    return out


def _episodes(ticks: list[int], segments: list[int], starts: list[tuple[int, int]]
              ) -> IntArray:
    """Episode number per pair: (segment, newest start at or before the tick), renumbered."""
    start_ticks = sorted(t for t, _ in starts)
    keys_ = [(seg, bisect.bisect_right(start_ticks, t)) for t, seg in
             zip(ticks, segments, strict=True)]
    numbers: dict[tuple[int, int], int] = {}
    out = np.empty(len(keys_), dtype=np.int64)
    for i, k in enumerate(keys_):
        if k not in numbers:
            numbers[k] = len(numbers)
        out[i] = numbers[k]
    return out


def pairs_from_log(path: str | Path, *, robot: str | None = None,
                   profile: RobotProfile | None = None) -> Pairs:
    """The learned pairs of a session log (module docstring); ``ValueError`` if it has none.

    ``profile`` names the fields (default: the log's own, :meth:`SessionInfo.profile`).
    """
    from roger_daemon.recording.session_read import read_timeline

    src = Path(path)
    tl = read_timeline([src], robot=robot, predictions=False)
    pairs = [(seg_no, p) for seg_no, seg in enumerate(tl.segments) for p in seg.pairs]
    if not pairs:
        raise ValueError(f"{src}: no learned pairs for robot {tl.robot!r}")
    prof = profile or tl.info.profile()
    if tl.dims is not None and prof.dims != tl.dims:
        raise ValueError(f"profile {prof.name!r} is {prof.dims.x}-D -> {prof.dims.y}-D, the "
                         f"log's robot {tl.dims.x}-D -> {tl.dims.y}-D")
    around = _around([src], tl.robot)
    ticks = [p.tick for _, p in pairs]
    info = tl.info
    rate = info.raw.get("rate_hz", "")
    try:
        fps = float(rate) if rate else prof.rate_hz
    except ValueError:
        fps = prof.rate_hz
    meta = {k: info.raw[k] for k in ("learner_params", "seed", "model", "session_id")
            if info.raw.get(k)}
    meta["source_log"] = src.name
    return Pairs(
        x=np.array([p.x for _, p in pairs], dtype=np.float64),
        y=np.array([p.y for _, p in pairs], dtype=np.float64),
        tick=np.array(ticks, dtype=np.int64),
        episode=_episodes(ticks, [s for s, _ in pairs], around.starts),
        label=[p.label for _, p in pairs],
        source=[around.learned_source.get(p.index) or around.action_source.get(p.tick, "")
                for _, p in pairs],
        profile=prof, fps=fps, robot=tl.robot, task=prof.task, meta=meta)

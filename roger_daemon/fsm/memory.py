"""What the robot remembers of its recent past, as features for the learned transitions.

The hand-coded demonstrator's transitions depend on memory and timers (which way the ball
went, how long it has been lost, when a motion ends: docs/demonstrator.md); its policies do
not. A learned controller that must choose among ROGER's experts at an aliased perception
needs the same kind of information, and the robot has it without any label: its own
perception history and its own commands (docs/autonomy.md, "Features").

:class:`MemorySpec` says where things are in a robot's vectors (data, not code: the AIBO's is
:func:`roger_daemon.fsm.profiles.aibo_memory`); :class:`Memory` keeps, tick by tick,

* per tracked blob (a colour class with image x, y and size): seconds since it was last seen
  and the bearing at which it was last seen, carried along by the robot's own turn commands
  (odometry);
* per sign of the action indicator (kick +, trap -): seconds since the robot last started
  that motion;
* seconds spent in the controller's current state (given by the caller).

:meth:`Memory.features` is the vector the transition model sees: the compact perception (per
blob seen, x and size, plus the scaled proprioceptive inputs) followed by those memories, each
scaled to about [-1, 1] and every clock capped at ``horizon_s``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["Memory", "MemorySpec"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MemorySpec:
    """Where a robot's blobs, head and commands are (indices into x and y), and the clocks.

    ``blobs``: ``(name, index of x)`` per tracked colour class; its (x, y, size) are at that
    index and the next two, size < 0 meaning "not seen". ``proprio``: ``(index, offset,
    scale)`` of inputs used as they are, scaled to ``(x - offset) / scale``. ``pan``: the head
    pan input (rad) that turns an image x into a bearing, ``pan - x * half_fov``. ``turn``: the
    command index of the turn rate (rad/s), for odometry. ``indicator``: the command index of a
    signed action indicator (``|y| >= threshold`` starts a motion), or ``None``.
    """

    blobs: tuple[tuple[str, int], ...]
    proprio: tuple[tuple[int, float, float], ...]
    pan: int | None
    half_fov: float
    turn: int | None
    indicator: int | None
    threshold: float = 0.5
    hz: float = 30.0
    horizon_s: float = 5.0

    def __post_init__(self) -> None:
        if not self.hz > 0 or not self.horizon_s > 0 or not self.half_fov >= 0:
            raise ValueError(f"MemorySpec: hz and horizon_s must be > 0 and half_fov >= 0, got "
                             f"{self.hz}, {self.horizon_s}, {self.half_fov}")
        for _, _, scale in self.proprio:
            if not scale > 0:
                raise ValueError(f"MemorySpec: a proprio scale must be > 0, got {scale}")

    @property
    def dim(self) -> int:
        """Length of :meth:`Memory.features`: 3 per blob and the proprio inputs (the compact
        perception), then 1 (time in state) + 2 per blob + 2 indicator clocks."""
        n = len(self.blobs)
        return 3 * n + len(self.proprio) + 1 + 2 * n + (2 if self.indicator is not None else 0)

    def names(self) -> list[str]:
        """A name per feature, in :meth:`Memory.features` order (for the inspectable FSM)."""
        out: list[str] = []
        for name, _ in self.blobs:
            out += [f"{name}_seen", f"{name}_x", f"{name}_size"]
        out += [f"x[{i}]" for i, _, _ in self.proprio]
        out.append("time_in_state")
        out += [f"since_{name}_seen" for name, _ in self.blobs]
        out += [f"{name}_bearing" for name, _ in self.blobs]
        if self.indicator is not None:
            out += ["since_positive_indicator", "since_negative_indicator"]
        return out

    def check_dims(self, d_x: int, d_y: int) -> None:
        """Raise ``ValueError`` if an index is outside a d_x-input, d_y-output robot."""
        xs = [i + k for _, i in self.blobs for k in range(3)] + [i for i, _, _ in self.proprio]
        xs += [] if self.pan is None else [self.pan]
        ys = [i for i in (self.turn, self.indicator) if i is not None]
        if any(not 0 <= i < d_x for i in xs) or any(not 0 <= i < d_y for i in ys):
            raise ValueError(f"MemorySpec: an index is outside x ({d_x}) or y ({d_y})")


class Memory:
    """The running memories of :class:`MemorySpec` (one per stream: a demonstration or the
    robot acting)."""

    def __init__(self, spec: MemorySpec) -> None:
        self.spec = spec
        self._dt = 1.0 / spec.hz
        # the indices features() reads, as arrays (one vectorised pass per tick)
        self.blob_x = self._blob_x = np.array([i for _, i in spec.blobs], dtype=np.int64)
        self.proprio = self._proprio = np.array([i for i, _, _ in spec.proprio], dtype=np.int64)
        self.offset = self._offset = np.array([o for _, o, _ in spec.proprio], dtype=np.float64)
        self.scale = self._scale = np.array([s for _, _, s in spec.proprio], dtype=np.float64)
        self.reset()
        self.config = self.kernel_config()

    def reset(self) -> None:
        """A new episode: nothing seen, no motion started, no command yet."""
        cap = self.spec.horizon_s
        n = len(self.spec.blobs)
        # one buffer [since (n), bearing (n), since_motion (2), last indicator], the views
        # below into it: the compiled kernels (.jit_fsm) advance it in place
        self.buffer = np.zeros(2 * n + 3)
        self.since = self.buffer[:n]
        self.bearing = self.buffer[n:2 * n]
        self.since_motion = self.buffer[2 * n:2 * n + 2]  # positive, negative indicator
        self.since[:] = cap
        self.since_motion[:] = cap
        self._started = False

    @property
    def _last_indicator(self) -> float:
        return float(self.buffer[-1])

    @_last_indicator.setter
    def _last_indicator(self, value: float) -> None:
        self.buffer[-1] = value

    def kernel_config(self) -> FloatArray:
        """The spec's scalars as :func:`.jit_fsm.advance` reads them (``CFG_FIELDS``)."""
        spec = self.spec

        def index(i: int | None) -> float:
            return -1.0 if i is None else float(i)

        return np.array([self._dt, spec.horizon_s, spec.half_fov, index(spec.pan),
                         index(spec.turn), index(spec.indicator), spec.threshold])

    def update(self, x: FloatArray, previous_command: FloatArray | None) -> None:
        """Advance one tick: the perception ``x`` and the command executed since the last
        tick (``None`` on an episode's first tick)."""
        spec, dt, cap = self.spec, self._dt, self.spec.horizon_s
        turn = 0.0
        indicator = 0.0
        if previous_command is not None:
            if spec.turn is not None:
                turn = float(previous_command[spec.turn]) * dt
            if spec.indicator is not None:
                v = float(previous_command[spec.indicator])
                indicator = math.copysign(1.0, v) if abs(v) >= spec.threshold else 0.0
        pan = 0.0 if spec.pan is None else float(x[spec.pan])
        for k, (_, i) in enumerate(spec.blobs):
            if x[i + 2] > 0:
                self.since[k] = 0.0
                self.bearing[k] = pan - float(x[i]) * spec.half_fov
            else:
                self.since[k] = min(cap, self.since[k] + dt)
                self.bearing[k] = math.remainder(self.bearing[k] - turn, math.tau)
        for k, sign in enumerate((1.0, -1.0)):
            onset = indicator == sign and self._last_indicator != sign
            self.since_motion[k] = 0.0 if onset else min(cap, self.since_motion[k] + dt)
        self._last_indicator = indicator

    def features(self, x: FloatArray, ticks_in_state: int) -> FloatArray:
        """The transition model's input at this tick (module docstring), length ``spec.dim``."""
        cap = self.spec.horizon_s
        n, p = len(self._blob_x), len(self._proprio)
        out = np.empty(self.spec.dim)
        size = x[self._blob_x + 2]
        seen = (size > 0).astype(np.float64)
        out[0:3 * n:3] = seen
        out[1:3 * n:3] = x[self._blob_x] * seen
        out[2:3 * n:3] = size * seen
        k = 3 * n + p
        out[3 * n:k] = (x[self._proprio] - self._offset) / self._scale
        out[k] = min(ticks_in_state * self._dt, cap) / cap
        out[k + 1:k + 1 + n] = self.since / cap
        out[k + 1 + n:k + 1 + 2 * n] = self.bearing / math.pi
        if self.spec.indicator is not None:
            out[k + 1 + 2 * n:] = self.since_motion / cap
        return out

    # -- state (a learning stream continues exactly after a checkpoint) -------------------------

    def state_arrays(self) -> dict[str, FloatArray]:
        """The memories as named arrays."""
        return {"since": self.since.copy(), "bearing": self.bearing.copy(),
                "since_motion": self.since_motion.copy(),
                "last_indicator": np.array([self._last_indicator])}

    def load_arrays(self, arrays: dict[str, npt.ArrayLike]) -> None:
        """Restore :meth:`state_arrays`; raises ``ValueError`` on a shape mismatch."""
        n = len(self.spec.blobs)
        since = np.asarray(arrays["since"], dtype=np.float64)
        bearing = np.asarray(arrays["bearing"], dtype=np.float64)
        motion = np.asarray(arrays["since_motion"], dtype=np.float64)
        if since.shape != (n,) or bearing.shape != (n,) or motion.shape != (2,):
            raise ValueError("Memory: saved arrays do not match the spec's blobs")
        self.since[:], self.bearing[:], self.since_motion[:] = since, bearing, motion
        self._last_indicator = float(np.asarray(arrays["last_indicator"]).reshape(-1)[0])


def spec_from_mapping(data: dict[str, object]) -> MemorySpec:
    """A :class:`MemorySpec` from its JSON form (:func:`spec_to_mapping`)."""
    def pairs(v: object) -> tuple[tuple[str, int], ...]:
        assert isinstance(v, Sequence)
        return tuple((str(a), int(b)) for a, b in v)

    def triples(v: object) -> tuple[tuple[int, float, float], ...]:
        assert isinstance(v, Sequence)
        return tuple((int(a), float(b), float(c)) for a, b, c in v)

    def opt(v: object) -> int | None:
        return None if v is None else int(v)  # type: ignore[call-overload]

    return MemorySpec(blobs=pairs(data["blobs"]), proprio=triples(data["proprio"]),
                      pan=opt(data["pan"]), half_fov=float(data["half_fov"]),  # type: ignore[arg-type]
                      turn=opt(data["turn"]), indicator=opt(data["indicator"]),
                      threshold=float(data["threshold"]), hz=float(data["hz"]),  # type: ignore[arg-type]
                      horizon_s=float(data["horizon_s"]))  # type: ignore[arg-type]


def spec_to_mapping(spec: MemorySpec) -> dict[str, object]:
    """The JSON form of a :class:`MemorySpec` (stored in the FSM's state dict)."""
    return {"blobs": [list(b) for b in spec.blobs], "proprio": [list(p) for p in spec.proprio],
            "pan": spec.pan, "half_fov": spec.half_fov, "turn": spec.turn,
            "indicator": spec.indicator, "threshold": spec.threshold, "hz": spec.hz,
            "horizon_s": spec.horizon_s}

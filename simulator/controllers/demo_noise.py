"""Perturbed demonstrations: the demonstrator's command is learned clean, executed with noise.

A learner's small errors take the robot to states the demonstrator never visits (a ball at
the image's edge, the head tilted low), and there no expert has data (docs/goal-scoring.md,
"Split gates": covariate shift).  Disturbing the demonstrator while it demonstrates (DART,
Laskey et al., CoRL 2017) makes the demonstrations visit such states, and the *recorded*
command, the demonstrator's own, says how it recovers from them.  The demonstrator's
decision is unchanged; only what the robot executes is perturbed, and the demonstrator's
odometry sees what was executed.

Noise: per walking and head command (``NOISY``), a Gaussian of standard deviation
``scale × range`` (``protocols.aibo.ACTION_RANGES``), held for ``hold`` ticks and redrawn
(piecewise constant, so it moves the robot instead of averaging out at 30 Hz); the executed
entries are clipped to their ranges.  The tail and the motion indicator are never perturbed.
``scale = 0`` is the paper's protocol exactly.

Used by ``roger hcc --role demonstrator --demo-noise F`` and by ``roger experiment
goal-scoring --demo-noise F`` (in-process one generator for the stream, on the Zenoh path one
per start location: :func:`location_seed`; docs/goal-scoring.md, "Perturbed demonstrations").
:func:`seeded` is the one place the noise's generator is made from a seed.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from protocols.aibo import ACTION_NAMES, ACTION_RANGES

__all__ = ["NOISE_STREAM", "NOISY", "DemoNoise", "location_seed", "seeded"]

#: The perturbed action entries: walk forward, sideways, turn; head tilt, pan, nod.
NOISY = tuple(ACTION_NAMES.index(n) for n in ("walk_forward", "walk_left", "walk_turn",
                                               "head_tilt", "head_pan", "head_nod"))

#: The noise generator's stream beside a demonstration's seed: ``default_rng([seed, it])``.
NOISE_STREAM = 0x4441

_LOW = np.array([ACTION_RANGES[i][0] for i in NOISY])
_HIGH = np.array([ACTION_RANGES[i][1] for i in NOISY])


class DemoNoise:
    """The executed command's disturbance (module docstring), seeded by ``rng``."""

    def __init__(self, scale: float, rng: np.random.Generator, hold: int = 15) -> None:
        if not 0.0 <= scale <= 0.5:
            raise ValueError(f"demonstration noise must be in [0, 0.5] of each range, got "
                             f"{scale!r}")
        if hold < 1:
            raise ValueError(f"noise hold must be >= 1 tick, got {hold!r}")
        self.scale = float(scale)
        self.hold = int(hold)
        self.rng = rng
        self._sd = self.scale * (_HIGH - _LOW)
        self._offset = np.zeros(len(NOISY))
        self._tick = 0

    def reset(self) -> None:
        """A new episode: the next command draws a new disturbance."""
        self._tick = 0

    def __call__(self, y: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The command executed for the demonstrator's ``y``."""
        if self._tick % self.hold == 0:
            self._offset = self.rng.normal(size=self._sd.size) * self._sd
        self._tick += 1
        out = np.array(y, dtype=np.float64)
        idx = list(NOISY)
        out[idx] = np.clip(out[idx] + self._offset, _LOW, _HIGH)
        return out


def seeded(scale: float, seed: int) -> DemoNoise | None:
    """The disturbance of scale ``scale`` drawn from the stream :data:`NOISE_STREAM` of
    ``seed``; None for ``scale == 0`` (nothing disturbed). A bad scale raises ValueError."""
    noise = DemoNoise(scale, np.random.default_rng([int(seed), NOISE_STREAM]))
    return noise if noise.scale > 0 else None


def location_seed(seed: int, location: int) -> int:
    """The ``--demo-noise-seed`` of one start location's demonstrations when each location
    runs in a process of its own (the experiment's Zenoh path): distinct per location, fixed
    by the demonstration's ``seed``."""
    return int(np.random.SeedSequence([int(seed), NOISE_STREAM, int(location)])
               .generate_state(1, dtype=np.uint32)[0])

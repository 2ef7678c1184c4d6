"""What every model constructor checks and derives from its arguments: the data dimensions, the
hyperparameters and the seed's two random streams.

Plain Python and numpy (no compiled code), so that the fast learner (:class:`.roger.Roger`,
:class:`.unimap.UnimapGP`) and the plain reference (:class:`.reference.ReferenceRoger`) share
one owner of these rules: the same arguments are refused, and the same seed gives the same
draws to both.
"""

from __future__ import annotations

import numpy as np

from roger_daemon.learner.params import RogerParams

__all__ = ["Seed", "check_dims", "resolve_model_args", "spawn_generators"]

Seed = int | np.random.Generator | None


def check_dims(d_x: object, d_y: object) -> tuple[int, int]:
    """Validate the data dimensions (positive integers)."""
    for name, v in (("d_x", d_x), ("d_y", d_y)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or int(v) < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    return int(d_x), int(d_y)  # type: ignore[call-overload]


def resolve_model_args(d_x: object, d_y: object, params: RogerParams | None
                       ) -> tuple[int, int, RogerParams]:
    """Validated ``(d_x, d_y, params)`` of a model constructor (paper defaults for ``None``;
    ``nu0`` resolved for ``d_x``, :meth:`RogerParams.for_dims`)."""
    dx, dy = check_dims(d_x, d_y)
    resolved = RogerParams() if params is None else params
    if not isinstance(resolved, RogerParams):
        raise TypeError(f"params must be a RogerParams, got {type(params).__name__}")
    resolved.check_dims(dx, dy)
    return dx, dy, resolved.for_dims(dx)


def spawn_generators(seed: Seed) -> tuple[np.random.Generator, np.random.Generator]:
    """Two independent streams from one seed: (learning, prediction).

    Predictions draw only from the second stream, so they never perturb learning.
    """
    if isinstance(seed, np.random.Generator):
        learn, predict = seed.spawn(2)
        return learn, predict
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer)):
        raise TypeError(f"seed must be an int, a numpy Generator or None, got {seed!r}")
    children = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(children[0]), np.random.default_rng(children[1])

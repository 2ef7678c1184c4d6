"""Hyperparameters of the ROGER learner: a frozen, validated value object.

The defaults are the paper's (Grollman & Jenkins, IROS 2010, section IV.A and Table I):
alpha = 0.5, mu0 = 0, kappa0 = 0.1, Lambda0 = 1 (read as the identity, roger-math.md §3),
nu0 = 24, theta_w = 0.1, theta_n = 0.1, beta = 300, P = 10.  The remaining fields are the
"fidelity switches" and open choices of roger-math.md §0 and §6, each with a documented default.

Every value is checked in ``__post_init__``; a bad one raises :class:`ParameterError`, whose
message names the parameter, its valid range and the value given.  Checks that need the data
dimensions (``nu0 > d_x - 1``, lengths of the affine scalings) run in
:meth:`RogerParams.check_dims`, which the models call on construction.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "EXPERT_CHOICES",
    "KERNEL_DIM_SCALINGS",
    "LIKELIHOOD_NORMALISERS",
    "ParameterError",
    "RogerParams",
]

KERNEL_DIM_SCALINGS = ("textbook", "grollman")
LIKELIHOOD_NORMALISERS = ("multivariate", "grollman")
EXPERT_CHOICES = ("argmax", "sample")


class ParameterError(ValueError):
    """A hyperparameter is outside its valid range (message: name, range, value given)."""


def _is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def _real(name: str, value: object, *, low: float | None = None, low_open: bool = True,
          allow_inf: bool = False) -> float:
    """Validate a real scalar; ``low`` is an open (or closed) lower bound."""
    if low is None:
        rng = "a finite float"
    else:
        rng = f"a float {'>' if low_open else '>='} {low:g}"
    if not _is_real(value):
        raise ParameterError(f"{name} must be {rng}, got {value!r}")
    v = float(value)  # type: ignore[arg-type]
    if math.isnan(v) or (math.isinf(v) and not (allow_inf and v > 0)):
        raise ParameterError(f"{name} must be {rng}, got {v!r}")
    if low is not None and (v <= low if low_open else v < low):
        raise ParameterError(f"{name} must be {rng}, got {v!r}")
    return v


def _integer(name: str, value: object, *, low: int) -> int:
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)
    if not ok and isinstance(value, float) and value.is_integer():
        ok, value = True, int(value)
    if not ok or int(value) < low:  # type: ignore[call-overload]
        raise ParameterError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)  # type: ignore[call-overload]


def _choice(name: str, value: object, choices: tuple[str, ...]) -> str:
    if value not in choices:
        names = ", ".join(map(repr, choices))
        raise ParameterError(f"{name} must be one of {names}, got {value!r}")
    return str(value)


def _vector(name: str, value: object, *, positive: bool) -> tuple[float, ...] | None:
    if value is None:
        return None
    kind = "finite floats > 0" if positive else "finite floats"
    rng = f"None or a non-empty sequence of {kind}"
    if isinstance(value, str | bytes) or not hasattr(value, "__iter__"):
        raise ParameterError(f"{name} must be {rng}, got {value!r}")
    out = []
    for v in value:
        if not _is_real(v) or not math.isfinite(float(v)) or (positive and float(v) <= 0):
            raise ParameterError(f"{name} must be {rng}, got {value!r}")
        out.append(float(v))
    if not out:
        raise ParameterError(f"{name} must be {rng}, got {value!r}")
    return tuple(out)


@dataclass(frozen=True)
class RogerParams:
    """ROGER hyperparameters (paper defaults) and implementation options.

    Parameters
    ----------
    alpha : float, default 0.5
        CRP concentration (paper Table I).  Larger values create experts more readily.
    mu0 : float, default 0.0
        Centre of the input-gate centres, the same value in every input dimension (NIW prior).
    kappa0 : float, default 0.1
        Pseudo-count of the gate-centre prior (NIW ``kappa0``).
    lambda0 : float, default 1.0
        Inverse-Wishart *scale* matrix of the gates, ``lambda0 * I`` (roger-math.md §3).
    nu0 : float, default 24.0
        Inverse-Wishart degrees of freedom; must exceed ``d_x - 1`` (checked per model).
    theta_w : float, default 0.1
        RBF kernel width (see ``kernel_dim_scaling``).
    theta_n : float, default 0.1
        Observation-noise variance ``s0^2`` of every sparse online GP expert.
    beta : int, default 300
        Capacity of each expert, in basis vectors.
    particles : int, default 10
        Number of particles ``P`` kept after resampling.
    kernel_dim_scaling : {"textbook", "grollman"}, default "textbook"
        ``"textbook"``: ``k(a, b) = exp(-|a - b|^2 / (2 theta_w^2))``.  ``"grollman"``: the
        squared distance is also divided by ``d_x``, as in Grollman's SOGP library (fidelity
        switch 1; effective length-scale ``theta_w * sqrt(d_x)``, 0.48 for the paper's 23-D).
        With the textbook kernel and ``theta_w = 0.1`` nearly every 23-D point is novel, so
        experts fill to ``beta`` and every update adds and deletes a basis vector.
    likelihood_normaliser : {"multivariate", "grollman"}, default "multivariate"
        Normaliser of an expert's Gaussian likelihood of ``y``: the correct
        ``-(d_y/2) log(2 pi s^2)`` or Grollman's 1-D ``-(1/2) log(2 pi s^2)`` (fidelity switch 2).
    novelty_threshold : float, default 1e-6
        A point becomes a basis vector iff its projection residual ``gamma >= threshold * k*``
        (relative test, Csató; equals Grollman's absolute 1e-6 since ``k* = 1``).  Basis vectors
        whose residual ``1/Q_ii`` falls below ``threshold / 1000`` are removed (geometric clean-up).
    expert_choice : {"argmax", "sample"}, default "argmax"
        How :meth:`Roger.predict_one` picks the expert of the MAP particle: most probable under
        the gate, or sampled from the gate probabilities as in the paper's Algorithm 2.  The
        default is deterministic: a 30 Hz controller does not chatter between branches where
        gates overlap, and replays reproduce predictions without replaying prediction draws
        (the paper itself replaces the draw by a transition model on the robot; the
        transitioner uses ``predict_multimap``).  ``"sample"`` draws from a generator of its
        own, so it never perturbs learning.
    predict_empty_expert : bool, default False
        Whether the empty "+1" expert takes part in prediction, as in the paper's Algorithm 2
        (``k = 1 : K + 1``).  It has no data: it predicts the prior (mean 0, i.e. the output
        offset, variance ``1 + theta_n``), which is no useful action, so by default only real
        experts compete and their gate probabilities sum to 1.  When on, it appears in the
        multimap with ``expert_id = -1``.
    prune_log_margin : float, default inf
        Opt-in speed-up, off by default.  Putatives whose *upper bound* on the log weight lies
        more than this below the best putative are given weight zero without evaluating their
        GP (e.g. 60: relative weight < exp(-60) ~ 1e-26).  This never changes the surviving
        putatives that carry weight, but it does change which negligible-weight putatives
        fill the remaining particle slots (and can leave fewer than ``particles``), so
        Algorithm 1 is only reproduced exactly with ``inf``.
    x_offset, x_scale, y_offset, y_scale : tuple of float or None
        Fixed affine scaling applied before learning: ``(x - x_offset) / x_scale`` and likewise
        for ``y``; predictions are mapped back.  Not learned from data.  The priors (``mu0 = 0``,
        unit scales, zero GP mean) assume roughly normalised data (roger-math.md pitfall 3).
    """

    alpha: float = 0.5
    mu0: float = 0.0
    kappa0: float = 0.1
    lambda0: float = 1.0
    nu0: float = 24.0
    theta_w: float = 0.1
    theta_n: float = 0.1
    beta: int = 300
    particles: int = 10
    kernel_dim_scaling: str = "textbook"
    likelihood_normaliser: str = "multivariate"
    novelty_threshold: float = 1e-6
    expert_choice: str = "argmax"
    predict_empty_expert: bool = False
    prune_log_margin: float = math.inf
    x_offset: tuple[float, ...] | None = None
    x_scale: tuple[float, ...] | None = None
    y_offset: tuple[float, ...] | None = None
    y_scale: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        s = object.__setattr__
        s(self, "alpha", _real("alpha", self.alpha, low=0.0))
        s(self, "mu0", _real("mu0", self.mu0))
        s(self, "kappa0", _real("kappa0", self.kappa0, low=0.0))
        s(self, "lambda0", _real("lambda0", self.lambda0, low=0.0))
        s(self, "nu0", _real("nu0", self.nu0, low=0.0))
        s(self, "theta_w", _real("theta_w", self.theta_w, low=0.0))
        s(self, "theta_n", _real("theta_n", self.theta_n, low=0.0))
        s(self, "beta", _integer("beta", self.beta, low=1))
        s(self, "particles", _integer("particles", self.particles, low=1))
        s(self, "kernel_dim_scaling",
          _choice("kernel_dim_scaling", self.kernel_dim_scaling, KERNEL_DIM_SCALINGS))
        s(self, "likelihood_normaliser",
          _choice("likelihood_normaliser", self.likelihood_normaliser, LIKELIHOOD_NORMALISERS))
        s(self, "novelty_threshold",
          _real("novelty_threshold", self.novelty_threshold, low=0.0, low_open=False))
        s(self, "expert_choice", _choice("expert_choice", self.expert_choice, EXPERT_CHOICES))
        if not isinstance(self.predict_empty_expert, bool):
            raise ParameterError(
                f"predict_empty_expert must be a bool, got {self.predict_empty_expert!r}")
        s(self, "prune_log_margin", _real("prune_log_margin", self.prune_log_margin, low=0.0,
                                          allow_inf=True))
        s(self, "x_offset", _vector("x_offset", self.x_offset, positive=False))
        s(self, "x_scale", _vector("x_scale", self.x_scale, positive=True))
        s(self, "y_offset", _vector("y_offset", self.y_offset, positive=False))
        s(self, "y_scale", _vector("y_scale", self.y_scale, positive=True))

    def check_dims(self, d_x: int, d_y: int) -> None:
        """Checks that depend on the data dimensions (run by the models on construction)."""
        if self.nu0 <= d_x - 1:
            raise ParameterError(
                f"nu0 must be a float > d_x - 1 = {d_x - 1} for d_x = {d_x}, got {self.nu0!r}")
        for name, want in (("x_offset", d_x), ("x_scale", d_x), ("y_offset", d_y),
                           ("y_scale", d_y)):
            value = getattr(self, name)
            if value is not None and len(value) != want:
                raise ParameterError(
                    f"{name} must be None or have length {want}, got length {len(value)}")

    # -- mapping round trip (TOML tables, JSON metadata) -------------------------------------

    def to_mapping(self) -> dict[str, Any]:
        """All fields as JSON-able values (tuples become lists); inverse of :meth:`from_mapping`."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and math.isinf(v):
                v = "inf"  # JSON has no infinity
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any]) -> RogerParams:
        """Build from a mapping such as a TOML table; unknown keys raise :class:`ParameterError`."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(mapping) - names)
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {', '.join(map(repr, unknown))}; "
                f"valid names are {', '.join(sorted(names))}")
        kwargs = dict(mapping)
        if kwargs.get("prune_log_margin") == "inf":
            kwargs["prune_log_margin"] = math.inf
        return cls(**kwargs)

    def replace(self, **changes: Any) -> RogerParams:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

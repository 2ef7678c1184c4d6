"""Hyperparameters of the ROGER learner: a frozen, validated value object.

The defaults are the paper's (Grollman & Jenkins, IROS 2010, section IV.A and Table I):
alpha = 0.5, mu0 = 0, kappa0 = 0.1, Lambda0 = 1 (read as the identity, docs/learner-math.md),
nu0 = 24 (= d_x + 1 for the paper's 23-D input: the default ``nu0 = None`` is ``d_x + 1`` for
the data's own d_x, :meth:`RogerParams.for_dims`), theta_w = 0.1, theta_n = 0.1, beta = 300,
P = 10.  The remaining fields are the implementation choices the paper leaves open and the
levers beyond the paper (issue 13), each with a documented default; with every lever at its
default (``RogerParams()``, the ``"paper"`` preset) the model is exactly the paper's
Algorithm 1.  :data:`PRESETS` names whole settings
(``RogerParams.preset("default")``).

Every value is checked in ``__post_init__``; a bad one raises :class:`ParameterError`, whose
message names the parameter, its valid range and the value given.  Checks that need the data
dimensions (``nu0 > d_x - 1``, lengths of the affine scalings) run in
:meth:`RogerParams.check_dims`, which the models call on construction.
:func:`range_scaling` turns declared ranges of the inputs and outputs into the fixed scaling
(``RogerParams.preset("default", x_ranges=..., y_ranges=...)``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "EXPERT_CHOICES",
    "GP_PRIOR_MEANS",
    "KERNEL_DIM_SCALINGS",
    "LIKELIHOOD_NORMALISERS",
    "PRESETS",
    "ParameterError",
    "RogerParams",
    "range_scaling",
]

KERNEL_DIM_SCALINGS = ("textbook", "grollman")
LIKELIHOOD_NORMALISERS = ("multivariate", "grollman")
EXPERT_CHOICES = ("argmax", "sample")
GP_PRIOR_MEANS = ("zero", "expert")

#: Named settings, one table: each preset is a set of changes to ``RogerParams()`` (the paper).
#: ``"paper"``: the paper's literal numbers, every lever off (Algorithm 1 exactly).
#: ``"default"``: the levers of issue 13 at the values measured to work in closed loop on
#: range-scaled AIBO data (theta_n = 1e-4, theta_w = 10, each expert's GP prior mean = its data's
#: running mean); final values are chosen from the goal-scoring experiment.  The per-robot
#: input/output scaling and input weights are not here (they depend on the robot's dimensions):
#: the daemon config applies the AIBO's by default (``roger_daemon.config``).
PRESETS: Mapping[str, Mapping[str, Any]] = {
    "paper": {},
    "default": {
        "theta_w": 10.0,
        "theta_n": 1e-4,
        # a broad kernel with the paper's 1e-6 admits near-dependent basis vectors: an
        # ill-conditioned K_B whose round-off decides the segmentation (NaN predictions in
        # closed loop, structure differing between BLAS kernels: docs/reproducibility.md)
        "novelty_threshold": 1e-3,
        "gp_prior_mean": "expert",
        "sticky_kappa": 0.0,
        "min_support": 20,
    },
}


class ParameterError(ValueError):
    """A hyperparameter is outside its valid range (message: name, range, value given)."""


#: ``(low, high)`` of each dimension
Ranges = Sequence[Sequence[float]]


def range_scaling(ranges: Ranges, name: str = "ranges"
                  ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(offset, scale)`` mapping each ``[low, high]`` onto ``[-1, 1]``: centre, half-width.

    >>> range_scaling([(-1.0, 1.0), (0.0, 4.0)])
    ((0.0, 2.0), (1.0, 2.0))
    """
    out: list[tuple[float, float]] = []
    for r in ranges:
        pair = tuple(r) if not isinstance(r, str | bytes) and hasattr(r, "__iter__") else ()
        if (len(pair) != 2 or not all(_is_real(v) and math.isfinite(float(v)) for v in pair)
                or float(pair[1]) <= float(pair[0])):
            raise ParameterError(
                f"{name} must be a sequence of (low, high) pairs of finite floats with "
                f"high > low, got {r!r}")
        out.append((float(pair[0]), float(pair[1])))
    if not out:
        raise ParameterError(f"{name} must not be empty")
    return (tuple(0.5 * (lo + hi) for lo, hi in out), tuple(0.5 * (hi - lo) for lo, hi in out))


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
    out: int = int(value)  # type: ignore[call-overload]
    return out


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
        Inverse-Wishart *scale* matrix of the gates, ``lambda0 * I`` (docs/learner-math.md §3).
    nu0 : float or None, default None
        Inverse-Wishart degrees of freedom; must exceed ``d_x - 1`` (checked per model).
        ``None``: ``d_x + 1``, the paper's choice (24 for its 23-D input) for any input size;
        the models resolve it on construction (:meth:`for_dims`), so their ``params.nu0`` is a
        number.
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
        unit scales, zero GP mean) assume roughly normalised data (docs/learner-math.md).
        ``theta_w``, ``mu0`` and ``lambda0`` are in these scaled units.  The daemon config fills
        them from the robot's documented sensor ranges (``protocols/AIBO.md``) by default.
    gp_prior_mean : {"zero", "expert"}, default "zero"
        Prior mean of each expert's GP.  ``"zero"``: the paper's (eq. 1).  ``"expert"``: the
        running mean of the outputs assigned to that expert (no labels), so that far from its
        data an expert predicts its typical action instead of 0 ("stand still, head up");
        exactly a zero-mean GP on ``y - m`` with ``m`` the expert's current mean (the
        predictive variance is unchanged).  The empty expert's mean stays 0.  Lever of issue 13.
    sticky_kappa : float >= 0 or inf, default 0.0
        Temporal stickiness of the partition prior (the paper's section V future work, after
        Fox et al. 2008): within each particle the expert of the previous point gets
        ``n_k + sticky_kappa`` instead of ``n_k`` as its CRP weight.  ``0`` is the paper's CRP;
        ``inf`` keeps every point with its predecessor's expert.
    min_support : int >= 0, default 0
        Prediction only: an expert with fewer points than this cannot win the gate (its gate
        probability is 0 in ``predict_one`` and ``predict_multimap``) unless no expert of the
        MAP particle has that many.  Tiny experts keep broad gates that win wherever the big
        experts' gates are small (issue 13).  ``0`` or ``1``: every expert competes (paper).
    input_weights : tuple of float >= 0, or None
        Per-dimension weights of the (scaled) input, used by the gates and the kernel alike:
        the model sees ``w_i * x_i``, so a weight ``w`` divides that dimension's kernel width by
        ``w``; a weight ``0`` drops the dimension (state-free inputs such as the AIBO's tail
        clock).  ``nu0`` must then exceed ``(kept dimensions) - 1``.  ``None``: all 1 (paper).
    """

    alpha: float = 0.5
    mu0: float = 0.0
    kappa0: float = 0.1
    lambda0: float = 1.0
    nu0: float | None = None
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
    gp_prior_mean: str = "zero"
    sticky_kappa: float = 0.0
    min_support: int = 0
    input_weights: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        s = object.__setattr__
        s(self, "alpha", _real("alpha", self.alpha, low=0.0))
        s(self, "mu0", _real("mu0", self.mu0))
        s(self, "kappa0", _real("kappa0", self.kappa0, low=0.0))
        s(self, "lambda0", _real("lambda0", self.lambda0, low=0.0))
        if self.nu0 is not None:
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
        s(self, "gp_prior_mean", _choice("gp_prior_mean", self.gp_prior_mean, GP_PRIOR_MEANS))
        s(self, "sticky_kappa", _real("sticky_kappa", self.sticky_kappa, low=0.0,
                                      low_open=False, allow_inf=True))
        s(self, "min_support", _integer("min_support", self.min_support, low=0))
        weights = _vector("input_weights", self.input_weights, positive=False)
        if weights is not None and (min(weights) < 0 or max(weights) <= 0):
            raise ParameterError(
                "input_weights must be None or a non-empty sequence of finite floats >= 0, "
                f"not all 0, got {self.input_weights!r}")
        s(self, "input_weights", weights)

    def model_dims(self, d_x: int) -> int:
        """Input dimensions the gates and kernel see: those with a non-zero input weight."""
        if self.input_weights is None:
            return d_x
        return sum(1 for w in self.input_weights if w != 0.0)

    def nu0_for(self, d_x: int) -> float:
        """``nu0`` for ``d_x`` inputs: the value given, else ``d_x + 1`` (the paper's 24 for 23).

        >>> RogerParams().nu0_for(23), RogerParams().nu0_for(30), RogerParams(nu0=40).nu0_for(3)
        (24.0, 31.0, 40.0)
        """
        return float(d_x + 1) if self.nu0 is None else self.nu0

    def for_dims(self, d_x: int) -> RogerParams:
        """These params with ``nu0`` resolved for ``d_x`` inputs (:meth:`nu0_for`)."""
        return self if self.nu0 is not None else dataclasses.replace(self, nu0=self.nu0_for(d_x))

    def check_dims(self, d_x: int, d_y: int) -> None:
        """Checks that depend on the data dimensions (run by the models on construction)."""
        for name, want in (("x_offset", d_x), ("x_scale", d_x), ("y_offset", d_y),
                           ("y_scale", d_y), ("input_weights", d_x)):
            value = getattr(self, name)
            if value is not None and len(value) != want:
                raise ParameterError(
                    f"{name} must be None or have length {want}, got length {len(value)}")
        d_m = self.model_dims(d_x)
        if self.nu0_for(d_x) <= d_m - 1:
            kept = "" if d_m == d_x else f" (input dimensions kept by input_weights: {d_m})"
            raise ParameterError(
                f"nu0 must be a float > d_x - 1 = {d_m - 1} for d_x = {d_m}{kept}, "
                f"got {self.nu0!r}")

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
        for name in ("prune_log_margin", "sticky_kappa"):
            if kwargs.get(name) == "inf":
                kwargs[name] = math.inf
        return cls(**kwargs)

    @classmethod
    def preset(cls, name: str, *, x_ranges: Ranges | None = None,
               y_ranges: Ranges | None = None, **changes: Any) -> RogerParams:
        """The named setting of :data:`PRESETS` (``"paper"`` or ``"default"``), then ``changes``.

        ``x_ranges`` / ``y_ranges``: the ``(low, high)`` range of every input / output; each is
        mapped onto [-1, 1] (:func:`range_scaling`), the scaled units the ``"default"``
        preset's numbers are for. ``changes`` (``x_scale=...`` too) override both.

        >>> RogerParams.preset("paper") == RogerParams()
        True
        >>> RogerParams.preset("default", theta_w=3.0).theta_w
        3.0
        >>> p = RogerParams.preset("default", x_ranges=[(0, 10)], y_ranges=[(-2, 2), (0, 1)])
        >>> p.x_offset, p.x_scale, p.y_offset, p.y_scale
        ((5.0,), (5.0,), (0.0, 0.5), (2.0, 0.5))
        """
        if name not in PRESETS:
            names = ", ".join(map(repr, PRESETS))
            raise ParameterError(f"preset must be one of {names}, got {name!r}")
        scaling: dict[str, Any] = {}
        for axis, ranges in (("x", x_ranges), ("y", y_ranges)):
            if ranges is not None:
                offset, scale = range_scaling(ranges, f"{axis}_ranges")
                scaling[f"{axis}_offset"], scaling[f"{axis}_scale"] = offset, scale
        return cls.from_mapping({**PRESETS[name], **scaling, **changes})

    def replace(self, **changes: Any) -> RogerParams:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

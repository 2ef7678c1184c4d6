"""Input checking and the fixed affine scaling of inputs and outputs (docs/learner-math.md).

The priors assume normalised data (``mu0 = 0``, unit gate scale, zero GP mean), so the params
may carry a fixed offset and scale for x and y.  They are configuration, never learned from the
data: ``x_s = (x - x_offset) / x_scale``, ``y_s = (y - y_offset) / y_scale``; a prediction
``(m, v)`` in scaled units maps back to ``(m * y_scale + y_offset, v * y_scale^2)``.

``input_weights`` then multiply the scaled input, and the dimensions with weight 0 are dropped:
the gates and the kernel see ``x_m = (w * x_s)[w != 0]`` (``params.model_dims(d_x)`` entries).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.params import RogerParams

__all__ = ["AffineScaling", "as_vector"]

FloatArray = npt.NDArray[np.float64]
_FLOAT64 = np.dtype(np.float64)


def as_vector(name: str, value: object, dim: int) -> FloatArray:
    """``value`` as a finite, writable float64 vector of length ``dim``, else ``ValueError``."""
    if (type(value) is np.ndarray and value.dtype is _FLOAT64 and value.shape == (dim,)
            and value.flags.writeable and all(map(math.isfinite, value.tolist()))):
        return value  # what the checks below return for it, without numpy's calls
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a sequence of {dim} finite floats: {exc}") from None
    if arr.shape != (dim,):
        raise ValueError(f"{name} must have shape ({dim},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if not arr.flags.writeable:  # a read-only array (np.frombuffer, a memory map) is another
        arr = arr.copy()  # type to numba: each kernel would compile again for it, mid-step
    return arr


def _scaled(name: str, v: FloatArray, offset: FloatArray, scale: FloatArray) -> FloatArray:
    """``(v - offset) / scale`` (docs/learner-math.md), refused if it overflows."""
    with np.errstate(over="ignore", invalid="ignore"):  # refused below, with the values
        out: FloatArray = (v - offset) / scale
    return _finite(name, v, out)


def _finite(name: str, v: FloatArray, out: FloatArray) -> FloatArray:
    if not np.isfinite(out).all():
        raise ValueError(f"{name} scaled to model units overflows float64: {name} = "
                         f"{v.tolist()} (finite, but too large for the configured "
                         "offset, scale and input weights)")
    return out


class AffineScaling:
    """The fixed scaling of one model (identity where the params give ``None``)."""

    def __init__(self, params: RogerParams, d_x: int, d_y: int) -> None:
        def vec(v: tuple[float, ...] | None, fill: float, d: int) -> FloatArray:
            return np.full(d, fill) if v is None else np.asarray(v, dtype=np.float64)

        self.x_offset = vec(params.x_offset, 0.0, d_x)
        self.x_scale = vec(params.x_scale, 1.0, d_x)
        self.y_offset = vec(params.y_offset, 0.0, d_y)
        self.y_scale = vec(params.y_scale, 1.0, d_y)
        self.identity_x = params.x_offset is None and params.x_scale is None
        self.identity_y = params.y_offset is None and params.y_scale is None
        self.d_model = params.model_dims(d_x)
        self.weights: FloatArray = np.ones(d_x)
        self.kept: npt.NDArray[np.int64] | None = None
        if params.input_weights is not None:
            w = np.asarray(params.input_weights, dtype=np.float64)
            self.kept = np.flatnonzero(w != 0.0)
            self.weights = w[self.kept]

    def x_in(self, x: FloatArray) -> FloatArray:
        """Raw input to model units (scaled, weighted, zero-weight dimensions dropped);
        ``ValueError`` when a finite input leaves float64's range on the way."""
        if self.identity_x and self.kept is None:
            return x
        with np.errstate(over="ignore", invalid="ignore"):  # refused below, with the values
            xs = x if self.identity_x else (x - self.x_offset) / self.x_scale
            if self.kept is not None:
                xs = xs[self.kept] * self.weights
        return _finite("x", x, xs)

    def y_in(self, y: FloatArray) -> FloatArray:
        """Raw output to model units (``ValueError`` as :meth:`x_in`)."""
        return y if self.identity_y else _scaled("y", y, self.y_offset, self.y_scale)

    def mean_out(self, mean: FloatArray) -> FloatArray:
        """Predictive mean back to raw output units."""
        return mean * self.y_scale + self.y_offset

    def var_out(self, var: float) -> FloatArray:
        """Scalar predictive variance (model units) to a per-output variance in raw units."""
        return var * self.y_scale**2

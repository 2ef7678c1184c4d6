"""The learned transitions' compiled kernels: one call per learned pair, one per acting tick.

:class:`~roger_daemon.fsm.controller.LearnedFSM` calls these instead of its readable numpy
code (:mod:`.memory`, :mod:`.transitions`), which stays the oracle: ``tests/test_fsm_fast.py``
checks that the memories, features and NIW statistics (the state dict's ``fsm.*`` arrays)
are the same bits, and the scores the same to rounding (docs/autonomy.md, *Cost*):

* :func:`advance` is :meth:`.Memory.update` then :meth:`.Memory.features`, element by element
  in the same operations (no fused multiply-add: numba compiles without ``fastmath``);
  ``math.remainder`` by :func:`_remainder` (exact, as IEEE 754's);
* :func:`observe` is :func:`advance` then :meth:`.TransitionModel.learn_one`'s rank-1 NIW
  update (docs/learner-math.md §3.2), the same products in the same order;
* :func:`choose` is :func:`advance` then the scores of :meth:`.TransitionModel.log_scores`
  from the pairs' Student-t terms (§3.3), computed from ``Lambda_n`` by the learner's
  compiled Cholesky factor and inverse (engine/jit_cholesky.py) when a pair has learned since
  (``valid``), and :meth:`.LearnedFSM.choose`'s pick. Its
  floats differ from LAPACK's factor and inverse in the last bits only (a quadratic form
  ``|L^-1 u|^2`` instead of ``u' P u``); they enter no state and no replay.

The kernels are in ``roger compile``'s list (:func:`warm`, called by
:mod:`roger_daemon.learner.engine.jit_warm`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_cholesky import cholesky_lower, lower_inverse_transposed
from roger_daemon.learner.engine.jit_compile import compiled

__all__ = ["CFG_FIELDS", "AdvanceArgs", "advance", "choose", "observe", "predictive", "warm"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
#: :func:`advance`'s arguments (``_Track.kernel_args`` in :mod:`.controller`)
AdvanceArgs = tuple[FloatArray, FloatArray, bool, IntArray, IntArray, FloatArray, FloatArray,
                    FloatArray, FloatArray, int, FloatArray]

#: ``cfg``'s fields (:meth:`.Memory.kernel_config`); an absent index is -1
CFG_FIELDS = ("dt", "horizon_s", "half_fov", "pan", "turn", "indicator", "threshold")


@compiled()
def _remainder(x: float, y: float) -> float:  # pragma: no cover - compiled
    """IEEE 754 remainder of ``x`` by ``y > 0`` (``math.remainder``): ``fmod`` is exact, and
    so is the one subtraction of ``y`` (Sterbenz), ties to an even quotient."""
    r = np.fmod(x, y)
    half = 0.5 * y
    if abs(r) > half or (abs(r) == half and np.fmod(abs((x - r) / y), 2.0) == 1.0):
        r = r - math.copysign(y, r)
    return float(r)


@compiled()
def advance(x: FloatArray, cmd: FloatArray, has_cmd: bool, blob_x: IntArray, proprio: IntArray,
            offset: FloatArray, scale: FloatArray, cfg: FloatArray, mem: FloatArray, ticks: int,
            out: FloatArray) -> bool:  # pragma: no cover - compiled
    """:meth:`.Memory.update` and :meth:`.Memory.features` (module docstring). ``mem``: the
    memory's buffer ``[since (n), bearing (n), since_motion (2), last indicator]``; ``out``:
    the features. Returns whether they are all finite."""
    dt, cap, half_fov, thr = cfg[0], cfg[1], cfg[2], cfg[6]
    pan_i, turn_i, ind_i = int(cfg[3]), int(cfg[4]), int(cfg[5])
    n, p = blob_x.shape[0], proprio.shape[0]
    turn = 0.0
    indicator = 0.0
    if has_cmd:
        if turn_i >= 0:
            turn = cmd[turn_i] * dt
        if ind_i >= 0:
            v = cmd[ind_i]
            indicator = math.copysign(1.0, v) if abs(v) >= thr else 0.0
    pan = 0.0 if pan_i < 0 else x[pan_i]
    for k in range(n):
        i = blob_x[k]
        if x[i + 2] > 0:
            mem[k] = 0.0
            mem[n + k] = pan - x[i] * half_fov
        else:
            mem[k] = min(cap, mem[k] + dt)
            mem[n + k] = _remainder(mem[n + k] - turn, 2.0 * math.pi)
    last = mem[2 * n + 2]
    for k in range(2):
        sign = 1.0 if k == 0 else -1.0
        onset = indicator == sign and last != sign
        mem[2 * n + k] = 0.0 if onset else min(cap, mem[2 * n + k] + dt)
    mem[2 * n + 2] = indicator
    for k in range(n):
        size = x[blob_x[k] + 2]
        seen = 1.0 if size > 0 else 0.0
        out[3 * k] = seen
        out[3 * k + 1] = x[blob_x[k]] * seen
        out[3 * k + 2] = size * seen
    for j in range(p):
        out[3 * n + j] = (x[proprio[j]] - offset[j]) / scale[j]
    k0 = 3 * n + p
    out[k0] = min(ticks * dt, cap) / cap
    for k in range(n):
        out[k0 + 1 + k] = mem[k] / cap
        out[k0 + 1 + n + k] = mem[n + k] / math.pi
    if ind_i >= 0:
        out[k0 + 1 + 2 * n] = mem[2 * n] / cap
        out[k0 + 2 + 2 * n] = mem[2 * n + 1] / cap
    finite = True
    for j in range(out.shape[0]):
        if not math.isfinite(out[j]):
            finite = False
    return finite


@compiled()
def niw_update(r: int, phi: FloatArray, count: IntArray, mu: FloatArray, lam: FloatArray,
               valid: BoolArray, kappa0: float) -> None:  # pragma: no cover - compiled
    """:meth:`.TransitionModel.learn_one`'s rank-1 update of pair row ``r`` (§3.2)."""
    d = phi.shape[0]
    n = count[r]
    kappa = kappa0 + n
    f = kappa / (kappa + 1.0)
    g = kappa + 1.0
    u = np.empty(d)
    for i in range(d):
        u[i] = phi[i] - mu[r, i]
    for i in range(d):
        for j in range(d):
            lam[r, i, j] += (u[i] * u[j]) * f
    for i in range(d):
        mu[r, i] += u[i] / g
    count[r] = n + 1
    valid[r] = False


@compiled()
def observe(x: FloatArray, cmd: FloatArray, has_cmd: bool, blob_x: IntArray, proprio: IntArray,
            offset: FloatArray, scale: FloatArray, cfg: FloatArray, mem: FloatArray, ticks: int,
            out: FloatArray, r: int,
            count: IntArray, mu: FloatArray, lam: FloatArray, valid: BoolArray,
            kappa0: float) -> bool:  # pragma: no cover - compiled
    """:func:`advance`, then (``r >= 0`` and finite features) :func:`niw_update` of row ``r``;
    returns whether the features are finite."""
    finite = advance(x, cmd, has_cmd, blob_x, proprio, offset, scale, cfg, mem, ticks, out)
    if finite and r >= 0:
        niw_update(r, out, count, mu, lam, valid, kappa0)
    return finite


@compiled()
def predictive(r: int, count: IntArray, lam: FloatArray, linv: FloatArray, lnorm: FloatArray,
               kappa0: float, nu0: float) -> None:  # pragma: no cover - compiled
    """Row ``r``'s Student-t terms (§3.3): ``linv`` the inverse of the Cholesky factor of
    ``Lambda_n``, stored transposed (``linv[r][j, i] = (L^-1)[i, j]``, as the learner's
    :func:`.lower_inverse_transposed` writes it), ``lnorm = [log normaliser, (nu_t + D) / 2,
    nu_t, c]``."""
    d = lam.shape[1]
    chol = np.zeros((d, d))
    # the learner's own factor and inverse (engine/jit_cholesky.py), the textbook loops' floats
    logdet_lam = cholesky_lower(lam[r], d, 0.0, chol)
    linv[r, :, :] = 0.0
    lower_inverse_transposed(chol, d, linv[r])  # linv[r][j, i] = (L^-1)[i, j]
    n = float(count[r])
    kappa = kappa0 + n
    nu_t = nu0 + n - d + 1.0
    c = (kappa + 1.0) / (kappa * nu_t)
    logdet = d * math.log(c) + logdet_lam
    lnorm[r, 0] = (math.lgamma((nu_t + d) / 2.0) - math.lgamma(nu_t / 2.0)
                   - 0.5 * d * math.log(nu_t * math.pi) - 0.5 * logdet)
    lnorm[r, 1] = (nu_t + d) / 2.0
    lnorm[r, 2] = nu_t
    lnorm[r, 3] = c


@compiled()
def _best(rows: IntArray, phi: FloatArray, pairs: IntArray, count: IntArray, mu: FloatArray,
          lam: FloatArray, linv: FloatArray, lnorm: FloatArray, valid: BoolArray,
          kappa0: float, nu0: float, ids: IntArray,
          gate: FloatArray) -> int:  # pragma: no cover - compiled
    """:meth:`.LearnedFSM._best_row`: the table row of the best successor among ``rows``."""
    d = phi.shape[0]
    u = np.empty(d)
    best: float = -math.inf
    best_row = -1
    for q in range(rows.shape[0]):
        r = rows[q]
        row = -1
        for t in range(ids.shape[0]):
            if ids[t] == pairs[r, 1]:
                row = t  # the last, as the dict of expert ids
        if row < 0:
            continue
        if not valid[r]:
            predictive(r, count, lam, linv, lnorm, kappa0, nu0)
            valid[r] = True
        for i in range(d):
            u[i] = phi[i] - mu[r, i]
        delta = 0.0
        for i in range(d):
            acc = 0.0
            for j in range(i + 1):
                acc += linv[r, j, i] * u[j]  # (L^-1)[i, j], stored transposed
            delta += acc * acc
        delta /= lnorm[r, 3]
        score = (math.log(float(count[r])) + lnorm[r, 0]
                 - lnorm[r, 1] * math.log1p(delta / lnorm[r, 2]))
        if score + gate[row] > best:
            best, best_row = score + gate[row], row
    return best_row


@compiled()
def choose(x: FloatArray, cmd: FloatArray, has_cmd: bool, blob_x: IntArray, proprio: IntArray,
           offset: FloatArray, scale: FloatArray, cfg: FloatArray, mem: FloatArray, ticks: int,
           out: FloatArray,
           rows: IntArray, start: IntArray, pairs: IntArray, count: IntArray, mu: FloatArray,
           lam: FloatArray, linv: FloatArray, lnorm: FloatArray, valid: BoolArray,
           kappa0: float, nu0: float, ids: IntArray, probs: FloatArray,
           npts: IntArray) -> int:  # pragma: no cover - compiled
    """:func:`advance`, then :meth:`.LearnedFSM.choose`'s row: the best successor of the
    current state (``rows``), else of an episode's start (``start``), else the gate argmax
    (non-finite features score no successor, as in the readable code)."""
    advance(x, cmd, has_cmd, blob_x, proprio, offset, scale, cfg, mem, ticks, out)
    gate = np.empty(ids.shape[0])
    for t in range(ids.shape[0]):  # log g_j(x) up to a constant (controller.py)
        gate[t] = math.log(max(probs[t], 1e-300)) - math.log(max(1.0, float(npts[t])))
    row = _best(rows, out, pairs, count, mu, lam, linv, lnorm, valid, kappa0, nu0, ids, gate)
    if row < 0:
        row = _best(start, out, pairs, count, mu, lam, linv, lnorm, valid, kappa0, nu0, ids,
                    gate)
    if row < 0:
        row = 0
        for t in range(1, probs.shape[0]):
            if probs[t] > probs[row]:
                row = t
    return row


def warm() -> None:
    """Compile (or load from numba's cache) the kernels, with the types the FSM passes."""
    from roger_daemon.fsm.controller import LearnedFSM
    from roger_daemon.fsm.memory import MemorySpec

    spec = MemorySpec(blobs=(("ball", 0),), proprio=((3, 0.0, 1.0),), pan=3, half_fov=0.5,
                      turn=0, indicator=1)
    fsm = LearnedFSM(spec)
    x = np.array([0.1, 0.2, 0.3, 0.0])

    class _Table:
        expert_ids = [0]
        gate_probs = [1.0]
        n_points = [1]
        means = np.zeros((1, 2))

    for i in range(3):
        fsm.observe(x, np.array([0.1, 1.0]), 0, episode_start=i == 0)
    fsm.act(x, _Table())

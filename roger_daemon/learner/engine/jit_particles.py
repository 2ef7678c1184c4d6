"""Compiled kernels of the particle filter's bookkeeping (numba): gates and lineages.

Imported through :mod:`.jit`, like :mod:`.jit_kernels` (the experts' GP kernels):

* :func:`gate_update`, :func:`gate_log_predictive`: the NIW gates' rank-1 updates and
  Student-t log densities over a set of slots (:class:`.gate.GatePool`), in one call each;
  :func:`gate_crp_log_terms` adds each expert's CRP prior term (a step's putatives, a
  prediction's gate probabilities);
* :func:`trace_lineages`: particles' experts over the segmentation history's window, chased
  back through the stored ancestors (integers only: exact; :mod:`.history`).

Each is tested against a numpy or plain-Python oracle (tests/learner/test_gate.py,
tests/learner/test_jit.py).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_cholesky import cholesky_inverse_logdet
from roger_daemon.learner.engine.jit_compile import compiled
from roger_daemon.learner.engine.jit_scalar import student_t_normaliser

#: :func:`.jit_scalar.student_t_normaliser` compiled: the gates' Student-t constants after an
#: update (:func:`gate_update`) or a recomputation (:meth:`.gate.GatePool.update_many`)
gate_constants = compiled(nogil=True)(student_t_normaliser)

__all__ = ["gate_constants", "gate_crp_log_terms", "gate_log_predictive", "gate_update",
           "lineage_assignments", "trace_lineages"]

FloatArray = npt.NDArray[np.float64]

#: a gate's precision and ``log|Lambda|`` are recomputed from ``Lambda`` every this many
#: updates (:func:`gate_update`), so the Sherman-Morrison round-off cannot accumulate
GATE_REFRESH = 32


@compiled(nogil=True)
def gate_update(slots: npt.NDArray[np.int64], x: FloatArray, count: npt.NDArray[np.int64],
                kappa: FloatArray, nu: FloatArray, mu: FloatArray, lam: FloatArray,
                prec: FloatArray, logdet: FloatArray, lognorm: FloatArray, half_nu_d: FloatArray,
                inv_nu_c: FloatArray) -> None:
    """NIW rank-1 updates of the gates in ``slots`` (docs/learner-math.md §3.2), in place.

    ``Lambda += w u u^T`` with ``u = x - mu``, ``w = kappa / (kappa + 1)``; the precision by
    Sherman-Morrison, ``log|Lambda|`` by the determinant lemma, both recomputed from
    ``Lambda`` every :data:`GATE_REFRESH` inputs of a gate
    (:func:`.jit_kernels.cholesky_inverse_logdet`: no BLAS or LAPACK); the
    inputs counted, and the Student-t constants of §3.3 (:data:`gate_constants`) recomputed
    (:class:`.gate.GatePool`).
    """
    d = x.shape[0]
    u = np.empty(d)
    uw = np.empty(d)
    pu = np.empty(d)
    puf = np.empty(d)
    for s in slots:
        kp = kappa[s]
        kp1 = kp + 1.0
        w = kp / kp1
        for a in range(d):
            u[a] = x[a] - mu[s, a]
            uw[a] = u[a] * w
        for a in range(d):
            t = 0.0
            for b in range(d):
                t += prec[s, a, b] * u[b]
            pu[a] = t
        t = 0.0
        for a in range(d):
            t += uw[a] * pu[a]
        f = w / (1.0 + t)
        for a in range(d):
            puf[a] = pu[a] * f
        for a in range(d):
            ua = u[a]
            pa = pu[a]
            for b in range(d):
                lam[s, a, b] += ua * uw[b]
                prec[s, a, b] -= pa * puf[b]
            mu[s, a] += u[a] / kp1
        kappa[s] = kp1
        nu[s] += 1.0
        logdet[s] += math.log1p(t)
        count[s] += 1
        if count[s] % GATE_REFRESH == 0:  # bound the round-off: from Lambda by Cholesky
            fresh = cholesky_inverse_logdet(lam[s], d, 0.0, prec[s])
            if fresh == fresh:  # else (round-off left a pivot <= 0) the running values stay
                logdet[s] = fresh
        lognorm[s], half_nu_d[s], inv_nu_c[s] = gate_constants(kp1, nu[s], logdet[s], d)


@compiled(nogil=True)
def _gate_log_density(s: int, x: FloatArray, diff: FloatArray, mu: FloatArray,
                      prec: FloatArray, lognorm: FloatArray, half_nu_d: FloatArray,
                      inv_nu_c: FloatArray) -> float:
    """``log t_s(x)``, slot ``s``'s Student-t predictive (§3.3); ``diff`` is scratch."""
    d = x.shape[0]
    for a in range(d):
        diff[a] = x[a] - mu[s, a]
    delta = 0.0
    for a in range(d):
        t = 0.0
        for b in range(d):
            t += prec[s, a, b] * diff[b]
        delta += diff[a] * t
    log_t: float = lognorm[s] - half_nu_d[s] * math.log1p(delta * inv_nu_c[s])
    return log_t


@compiled(nogil=True)
def gate_log_predictive(slots: npt.NDArray[np.int64], x: FloatArray, mu: FloatArray,
                        prec: FloatArray, lognorm: FloatArray, half_nu_d: FloatArray,
                        inv_nu_c: FloatArray) -> FloatArray:
    """``log t_s(x)`` of the Student-t predictive of every gate in ``slots`` (§3.3)."""
    out = np.empty(slots.shape[0])
    diff = np.empty(x.shape[0])
    for j in range(slots.shape[0]):
        out[j] = _gate_log_density(slots[j], x, diff, mu, prec, lognorm, half_nu_d, inv_nu_c)
    return out


@compiled(nogil=True)
def gate_crp_log_terms(slots: npt.NDArray[np.int64], x: FloatArray, mu: FloatArray,
                       prec: FloatArray, lognorm: FloatArray, half_nu_d: FloatArray,
                       inv_nu_c: FloatArray, npts: npt.NDArray[np.int64],
                       out: FloatArray) -> None:
    """``out[s] = log t_s(x) + log n_s`` for every slot ``s`` of ``slots``: an expert's gate
    and CRP prior terms of a putative's log weight (§4; the normaliser ``N + alpha`` dropped),
    the log of the point count the C library's."""
    diff = np.empty(x.shape[0])
    for j in range(slots.shape[0]):
        s = slots[j]
        out[s] = _gate_log_density(s, x, diff, mu, prec, lognorm, half_nu_d, inv_nu_c)
        out[s] += math.log(npts[s])


@compiled(nogil=True)
def trace_lineages(ancestors: npt.NDArray[np.int32], experts: npt.NDArray[np.int64], n: int,
                   starts: npt.NDArray[np.int64]
                   ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """For each particle ``starts[s]`` of row ``n - 1``: ``ids[t, s] = experts[t, j_t]`` with
    ``j_{n-1} = starts[s]`` and ``j_{t-1} = ancestors[t, j_t]``, its expert at every row along
    its lineage (paper Algorithm 1's stored choices, read back), and ``origin[s] = j_{-1}``, the
    particle it descends from before row 0 (:mod:`.history`)."""
    m = starts.size
    ids = np.empty((n, m), dtype=np.int64)
    origin = np.empty(m, dtype=np.int64)
    for s in range(m):
        j = starts[s]
        for t in range(n - 1, -1, -1):
            ids[t, s] = experts[t, j]
            j = ancestors[t, j]
        origin[s] = j
    return ids, origin


@compiled(nogil=True)
def lineage_assignments(points: npt.NDArray[np.int64], settled: npt.NDArray[np.int64],
                        n_settled: int, ancestors: npt.NDArray[np.int32],
                        experts: npt.NDArray[np.int64], n: int, particle: int,
                        exception_points: npt.NDArray[np.int64],
                        exception_ids: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Particle ``particle``'s expert id at each of ``points`` (:mod:`.history`): a settled
    point's id, or at an exception (``exception_points``, ascending) the id of the boundary
    lineage it descends from; a window point's id along its lineage (:func:`trace_lineages`
    of the one particle). The caller checks that every point is below ``n_settled + n``."""
    out = np.empty(points.size, dtype=np.int64)
    ids, origins = trace_lineages(ancestors, experts, n, np.full(1, particle, dtype=np.int64))
    window = ids[:, 0]
    origin = origins[0]
    n_exc = exception_points.size
    for i in range(points.size):
        p = points[i]
        if p >= n_settled:
            out[i] = window[p - n_settled]
            continue
        out[i] = settled[p]
        if n > 0 and n_exc > 0:
            k = np.searchsorted(exception_points, p)
            if k < n_exc and exception_points[k] == p:
                out[i] = exception_ids[k, origin]
    return out

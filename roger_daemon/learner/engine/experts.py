"""Several experts per compiled call: a step's evaluation and its full experts' learning
(docs/performance.md, *Both cores in one step*).

The experts come as their slabs (:mod:`.jit_slab`) and their *homes*, the thread whose cache
last held each (:func:`.jit_batch.balanced_owners`); the work goes to the batched kernels,
:data:`.jit_constants.EVALUATION_WIDTH` or :data:`.jit_constants.WIDTH` experts per call,
spread over the threads (:mod:`.jit_batch`) when :func:`.jit_threads.batch_worth` says there
is enough work, else one thread takes them (:func:`.jit_evaluate.evaluate_experts`) or one
expert at a time (:func:`.jit_batch.learn_full_expert`).  Each expert's floats are those of a
call of its own, whatever the split.  What the results mean for an expert is the caller's
(:mod:`roger_daemon.learner.sogp_batch`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from itertools import accumulate
from typing import NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit

__all__ = ["Evaluated", "Outcomes", "SlabExpert", "evaluate_slabs", "learn_full_slabs"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class SlabExpert(Protocol):
    """An expert as the batched kernels take it: its slab and basis vectors, its home thread
    (``-1``: none yet; kept up to date here), and views of its buffers."""

    slab: FloatArray
    n: int
    home: int

    @property
    def buffers(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(B, A, C, Q)``: views of the slab (``C`` and ``Q`` packed)."""


class Evaluated(NamedTuple):
    """The experts at one input: expert ``e``'s ``[k, C k, k^T C k, k^T A]`` at
    ``packed[offsets[e]:]``, its predictive mean ``means[e]``, its latent variance
    ``latent[e]``."""

    means: FloatArray
    latent: FloatArray
    packed: FloatArray
    offsets: IntArray


class Outcomes(NamedTuple):
    """The full experts' steps 3-5 (:func:`.jit_batch.learn_batch`), one entry or row each:
    the outcome (:data:`.jit_constants.FUSED`, ``KEPT`` or ``DRIFTED``), ``gamma``, ``Q k``,
    after a fused step the diagonals it returns with ``diag(Q)``'s minimum and first argmax,
    the novelty test's margin, and whether the clean-up keeps every basis vector."""

    outcome: IntArray
    gamma: FloatArray
    e_hat: FloatArray
    diag: FloatArray
    dq: FloatArray
    dq_min: FloatArray
    dq_argmax: IntArray
    margin: FloatArray
    clean: npt.NDArray[np.bool_]


def _owners(experts: Sequence[SlabExpert], work: IntArray) -> tuple[IntArray, int]:
    """Each expert's thread for a batched kernel (:func:`.jit_batch.balanced_owners`: its home
    where the threads' loads allow), kept as its new home; and the number of threads."""
    groups = _jit.threads()
    owners = _jit.balanced_owners(np.array([e.home for e in experts], dtype=np.int64), work,
                                  groups, True)
    for expert, owner in zip(experts, owners.tolist(), strict=True):
        expert.home = owner
    return owners, groups


def evaluate_slabs(experts: Sequence[SlabExpert], x: FloatArray, gamma: float, k_star: float,
                   floor: float, prior_mean: bool, a_cols: int, d_y: int) -> Evaluated:
    """Every expert (``n >= 1`` basis vectors, all of one model: kernel ``gamma``, ``k*``,
    latent floor, prior-mean setting, ``a_cols`` columns of ``A`` and ``d_y`` outputs) at
    ``x`` (:func:`.jit_evaluate.evaluate_expert`)."""
    m = len(experts)
    ns = [e.n for e in experts]
    sizes = [2 * n + 1 + a_cols for n in ns]  # each one's terms, one after the other
    bounds = np.fromiter(accumulate(sizes, initial=0), dtype=np.int64, count=m + 1)
    out = Evaluated(np.empty((m, d_y)), np.empty(m), np.empty(int(bounds[m])), bounds[:m])
    batched = _jit.batch_worth(sum(n * (n + 1) for n in ns) // 2)  # packed entries in all
    ns_arr = np.array(ns, dtype=np.int64)
    slabs = [e.slab for e in experts]
    width = _jit.EVALUATION_WIDTH
    owners, groups = _owners(experts, ns_arr * (ns_arr + 1) // 2) if batched else (None, 0)
    with _jit.BATCH_LOCK if batched else contextlib.nullcontext():
        for lo in range(0, m, width):
            hi = min(lo + width, m)
            args = (_jit.padded(slabs, lo, width), hi - lo, ns_arr[lo:hi], x, gamma, k_star,
                    floor, prior_mean, out.packed, out.offsets[lo:hi], out.means[lo:hi],
                    out.latent[lo:hi])
            if owners is None:
                _jit.evaluate_experts(*args)
            else:
                _jit.terms_batch(*args, owners[lo:hi], groups)
    return out


def learn_full_slabs(experts: Sequence[SlabExpert], x: FloatArray, terms: FloatArray,
                     starts: IntArray, dgs: FloatArray, qs: FloatArray, rs: FloatArray,
                     cw: FloatArray, rule: FloatArray) -> Outcomes:
    """Steps 3-5 of full experts (``n`` basis vectors in buffers for ``n``, the same ``n``,
    one model), :func:`.jit_batch.learn_full_expert` each: expert ``i``'s kernel vector and
    ``C k`` at ``terms[starts[i]:]`` one after the other (as an evaluation packs them), its
    ``diag(C) + diag(Q)``, Csató's ``K1`` and ``K2`` rows of ``dgs``, ``qs``, ``rs``; ``cw``
    the deletion's column weights, ``rule`` the novelty test's constants and the clean-up's
    floor.  By :func:`.jit_batch.learn_batch` on several threads when there is enough work,
    else one expert at a time (faster there: docs/performance.md); the same floats."""
    m, n = len(experts), experts[0].n
    rows = np.empty((3, m, n))  # Q k, and the diagonals a fused step writes
    out = Outcomes(np.empty(m, dtype=np.int64), np.empty(m), rows[0], rows[1], rows[2],
                   np.empty(m), np.empty(m, dtype=np.int64), np.empty(m),
                   np.empty(m, dtype=np.bool_))
    if not _jit.batch_worth(m * n * (n + 1) // 2):
        for j, (expert, at) in enumerate(zip(experts, starts.tolist(), strict=True)):
            basis, coef, cbuf, qbuf = expert.buffers
            (out.outcome[j], out.gamma[j], out.dq_min[j], out.dq_argmax[j], out.margin[j],
             out.clean[j]) = _jit.learn_full_expert(
                basis, coef, cbuf, qbuf, x, terms[at: at + n], terms[at + n: at + 2 * n],
                dgs[j], qs[j], rs[j], cw, rule, out.e_hat[j], out.diag[j], out.dq[j])
        return out
    slabs = [e.slab for e in experts]
    owners, groups = _owners(experts, np.ones(m, dtype=np.int64))
    with _jit.BATCH_LOCK:
        for lo in range(0, m, _jit.WIDTH):
            hi = min(lo + _jit.WIDTH, m)
            _jit.learn_batch(_jit.padded(slabs, lo), hi - lo, x,
                             terms, starts[lo:hi], dgs[lo:hi], qs[lo:hi], rs[lo:hi], cw, rule,
                             out.e_hat[lo:hi], out.gamma[lo:hi], out.outcome[lo:hi],
                             out.diag[lo:hi], out.dq[lo:hi], out.dq_min[lo:hi],
                             out.dq_argmax[lo:hi], out.margin[lo:hi], out.clean[lo:hi],
                             owners[lo:hi], groups)
    return out

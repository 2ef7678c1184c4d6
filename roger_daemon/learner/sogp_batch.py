"""Several experts at once: one ROGER step's evaluation and its chosen experts' updates.

:func:`evaluate_many` is :meth:`.sogp.SparseOnlineGP.terms` of every expert a step evaluates
(and, with the noise added, :func:`predict_many` a prediction's); :func:`update_many` is
:meth:`.sogp.SparseOnlineGP.update` for each expert it updates, where the experts on the hot
path (full: ``n = beta`` basis vectors in buffers for ``beta``) take the fused add-then-delete
step (:mod:`.engine.jit_fused`).  The engine runs the experts' compiled kernels several per
call, on one thread or spread over the cores (:mod:`.engine.experts`; docs/performance.md,
*Both cores in one step*); each expert's floats are those of a call of its own."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.engine.experts import evaluate_slabs, learn_full_slabs
from roger_daemon.learner.engine.jit_slab import output_weights
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.sogp_steps import LATENT_FLOOR

__all__ = ["Evaluation", "evaluate_many", "predict_many", "update_evaluated", "update_many"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

Terms = tuple[FloatArray, FloatArray, FloatArray, float]


@dataclass(slots=True)
class Evaluation:
    """Experts evaluated at one input (:func:`evaluate_many`): ``means[j]`` (``d_y``) and
    ``latent[j]`` are expert ``gps[j]``'s predictive mean and latent variance (the floats of
    :meth:`.sogp.SparseOnlineGP.terms`); :meth:`terms` gives its full terms, built from the
    compiled ``packed[offsets[j]:]`` when first asked for (a step updates ~3 of the ~25 experts
    it evaluates) and kept in ``built``."""

    gps: Sequence[SparseOnlineGP]
    means: FloatArray
    latent: FloatArray
    packed: FloatArray
    offsets: IntArray
    built: list[Terms | None]

    def terms(self, j: int) -> Terms:
        """``gps[j].terms(x)``, from the compiled ``[k, C k, k^T C k, k^T A]`` of the call."""
        got = self.built[j]
        if got is None:
            gp = self.gps[j]
            start = int(self.offsets[j])
            got = gp.terms_from(self.packed[start: start + 2 * gp.n + 1 + gp.a_cols])
            self.built[j] = got
        return got


def evaluate_many(gps: Sequence[SparseOnlineGP], x: FloatArray) -> Evaluation:
    """Every expert of ``gps`` (all of one model: one kernel and prior-mean setting) at
    ``x``: by compiled calls of up to :data:`.jit.EVALUATION_WIDTH` experts each, on one
    thread (:func:`.jit_evaluate.evaluate_experts`) or, when :func:`.jit.batch_worth` says the
    experts are large enough for the threads, spread over them
    (:func:`.jit_batch.terms_batch`); the same floats as each expert's own ``terms``."""
    m = len(gps)
    if m == 0 or any(gp.n == 0 for gp in gps):  # an expert without basis vectors: its prior
        each = [gp.terms(x) for gp in gps]
        return Evaluation(gps, np.array([t[2] for t in each]),
                          np.array([t[3] for t in each], dtype=np.float64), np.empty(0),
                          np.zeros(m, dtype=np.int64), list(each))
    first = gps[0]
    kernel = first.kernel
    got = evaluate_slabs(gps, x, kernel.gamma, kernel.k_star, LATENT_FLOOR, first.prior_mean,
                         first.a_cols, first.d_y)
    return Evaluation(gps, got.means, got.latent, got.packed, got.offsets, [None] * m)


def predict_many(gps: Sequence[SparseOnlineGP], x: FloatArray, means: FloatArray,
                 variance: FloatArray) -> None:
    """``means[j], variance[j] = gps[j].predict(x)`` for every expert (a prediction's multimap,
    docs/learner-math.md §6): :func:`evaluate_many`, then the observation noise added to each
    latent variance, the same floats; all of one model (one kernel, noise and prior-mean
    setting)."""
    if not gps:
        return
    got = evaluate_many(gps, x)
    means[:] = got.means
    np.add(gps[0].noise, got.latent, out=variance)


def update_many(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                terms: Sequence[Terms | None]) -> None:
    """Learn the same pair in several distinct experts (one ROGER step's chosen experts).

    Equivalent to ``gp.update(x, y, t)`` for each (except that a non-novel point never
    re-inverts ``Q``: a projection update leaves ``Q`` unchanged).  The experts on the hot path
    (full, contiguous, the same ``n``, no drift in ``diag(Q)``) take ``Q k``, the novelty
    test and the fused add-then-delete step (:mod:`.engine.jit_fused`) in compiled calls of up to
    :data:`.jit.WIDTH` experts each (:func:`.jit_batch.learn_batch`); a non-novel point then
    gets its projection update here, and an expert whose ``Q`` drifted learns on its own.
    """
    full, alone = _hot_path(gps)
    _learn_alone(gps, alone, x, y, terms.__getitem__)
    if not full:
        return
    got: list[Terms] = []
    for j in full:
        t = terms[j]
        got.append(t if t is not None else gps[j].terms(x))
    n = gps[full[0]].n  # [k, C k] of each expert, one after the other, as an evaluation's
    _learn_full([gps[j] for j in full], x, y, np.concatenate([v for t in got for v in t[:2]]),
                np.arange(len(got), dtype=np.int64) * (2 * n), np.array([t[2] for t in got]),
                np.array([t[3] for t in got], dtype=np.float64), got.__getitem__)


def update_evaluated(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                     evaluated: Sequence[tuple[Evaluation, int] | None]) -> None:
    """:func:`update_many` with each expert's terms where the step's evaluation left them
    (``(evaluation, j)``: :meth:`Evaluation.terms` of ``j``; ``None``: not evaluated): the hot
    path's kernel vectors, ``C k``, means and latent variances are read off the evaluation's
    arrays, the same floats, without a tuple of terms per expert (a step updates ~10)."""
    full, alone = _hot_path(gps)
    _learn_alone(gps, alone, x, y,
                 lambda j: None if (ref := evaluated[j]) is None else ref[0].terms(ref[1]))
    if not full:
        return
    refs = [evaluated[j] for j in full]
    ev = refs[0][0] if refs[0] is not None else None
    if ev is None or gps[full[0]].prior_mean or any(r is None or r[0] is not ev for r in refs):
        update_many([gps[j] for j in full], x, y,
                    [None if r is None else r[0].terms(r[1]) for r in refs])
        return
    rows = np.array([r[1] for r in refs if r is not None], dtype=np.int64)
    _learn_full([gps[j] for j in full], x, y, ev.packed, ev.offsets[rows], ev.means[rows],
                ev.latent[rows], lambda i: ev.terms(int(rows[i])))


def _hot_path(gps: Sequence[SparseOnlineGP]) -> tuple[list[int], list[int]]:
    """Indices of the experts that take the batched fused step (full in buffers for exactly
    ``beta``, the same ``n`` as the first of them, ``diag(Q)`` without drift), and of the
    others."""
    full: list[int] = []
    alone: list[int] = []
    n = -1
    for j, gp in enumerate(gps):
        if gp.fusable() and (n < 0 or gp.n == n) and not gp.q_drifted():
            full.append(j)
            n = gp.n
        else:
            alone.append(j)
    return full, alone


def _learn_alone(gps: Sequence[SparseOnlineGP], alone: list[int], x: FloatArray, y: FloatArray,
                 terms_of: Callable[[int], Terms | None]) -> None:
    """The experts off the hot path (``alone``) learn one at a time, with their terms where
    known (``terms_of(j)``, ``None``: computed by the update)."""
    for j in alone:
        gps[j].update(x, y, terms_of(j))


def _learn_full(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray, terms: FloatArray,
                starts: IntArray, means: FloatArray, latent: FloatArray,
                terms_of: Callable[[int], Terms]) -> None:
    """Steps 3-6 of the full experts ``gps`` (of one model: the same ``n``, kernel, noise and
    novelty rule): expert ``i``'s kernel vector and ``C k`` at ``terms[starts[i]:]`` one after
    the other (as an evaluation packs them), its predictive mean and latent variance a row of
    ``means`` and ``latent`` (``terms_of(i)``: its terms, for the few that need them); by
    :func:`.jit_batch.learn_batch`, ``WIDTH`` at a time, on several threads
    (:func:`.jit.threads`) when there is enough work (:func:`.jit.batch_worth`); else its
    body's kernels one expert at a time (faster there: docs/performance.md); the same
    floats (:func:`.engine.experts.learn_full_slabs`).  Then each expert finishes the step
    (:meth:`.sogp.SparseOnlineGP.finish_kept`, :meth:`~.sogp.SparseOnlineGP.finish_fused`); one
    whose ``Q`` drifted learns on its own."""
    first = gps[0]
    m, n = len(gps), first.n
    denom = first.noise + latent
    rs = -1.0 / denom  # Csató's K2 per expert
    if first.prior_mean:  # the a1 column too (:meth:`.sogp.SparseOnlineGP._targets`)
        qs = np.empty((m, first.a_cols))  # and K1
        for j, gp in enumerate(gps):
            at = int(starts[j])
            y_ext, mean = gp.targets(y, means[j], terms[at: at + n])
            qs[j] = (y_ext - mean) / denom[j]
    else:
        qs = (y - means) / denom[:, None]
    rule = np.array([*first.novelty_constants(), first.cleanup_floor()])
    cw = output_weights(first.a_cols, first.d_y)
    dgs = np.array([gp.diag_cq() for gp in gps])
    out = learn_full_slabs(gps, x, terms, starts, dgs, qs, rs, cw, rule)
    margins, clean = out.margin.tolist(), out.clean.tolist()
    gammas = out.gamma.tolist()
    dq_mins, dq_argmaxes = out.dq_min.tolist(), out.dq_argmax.tolist()
    diags, dqs = list(out.diag), list(out.dq)  # row views, made in one call
    for j, (gp, outcome) in enumerate(zip(gps, out.outcome.tolist(), strict=True)):
        if outcome == _jit.DRIFTED:  # Q re-inverted and the point learned on its own
            gp.update(x, y, terms_of(j))
        elif outcome == _jit.KEPT:  # step 4a for the non-novel few
            gp.finish_kept(y, terms_of(j), out.e_hat[j], gammas[j], margins[j])
        else:
            gp.finish_fused(y, diags[j], dqs[j], dq_mins[j], dq_argmaxes[j], clean[j],
                            gammas[j], margins[j])

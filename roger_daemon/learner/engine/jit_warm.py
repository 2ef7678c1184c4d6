"""Compiling the learner's kernels ahead of use: :func:`.jit.warm_up`, and a share of them for
``roger compile`` (:mod:`roger_daemon.tools.compile_kernels`), which fills numba's on-disk
cache on every core.

Each *warmer* below calls one family of kernels with the argument types the learner passes
them, so that every signature a step uses exists before the step (tested:
``tests/learner/test_jit.py``).  On a cold cache (a fresh clone or install, or after a kernel's
source changed) compiling them all in one process took 58 s on a 2-core AMD EPYC, mostly the
two batched kernels (14 and 13 s) and the fused step (6 s).  The families' call trees share
only a few small kernels, so ``roger compile`` compiles them in several processes at once,
each a share, and writes numba's cache for every later process (``make test`` and ``make
demo`` run it first).  With a warm cache each share only loads the cache.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_constants import EVALUATION_WIDTH, padded
from roger_daemon.learner.engine.jit_slab import bind, new_slab, output_weights
from roger_daemon.learner.engine.jit_threads import use_threads

__all__ = ["WARMERS", "shares", "warm"]

FloatArray = npt.NDArray[np.float64]
N = 2  # basis vectors of the tiny experts the kernels are called on
_BASIS = np.zeros((N, 1))
_SYM = np.array([1.0, 0.0, 1.0])  # the identity, packed (:mod:`.packed`)


def _slab(cov: FloatArray, inv: FloatArray, coef: FloatArray) -> FloatArray:
    """The slab (:mod:`.jit_slab`) of a tiny expert with ``N`` basis vectors at 0 and the
    packed ``C``, ``Q`` and the ``A`` given (its columns: ``d_y = 1``, plus ``a1`` with two),
    as the batched kernels take them."""
    slab = new_slab(N, 1, coef.shape[1], 1)
    c, q, _, a, _ = bind(slab, N, 1, coef.shape[1], 1)
    c[:], q[:], a[:] = cov, inv, coef
    return slab


def _warm_learning() -> None:
    """``Q k``, the novelty test and the fused add-then-delete step, one expert or batched."""
    from roger_daemon.learner.engine import jit_batch as bk
    from roger_daemon.learner.engine import jit_fused as fk
    from roger_daemon.learner.engine import jit_kernels as k

    basis, sym = _BASIS, _SYM
    weights = output_weights(1, 1)  # as the learner passes them: read-only, its own signature
    vn, one = np.ones(N), np.ones(1)
    fk.rank_update_cq(sym.copy(), sym.copy(), N, N, 0, np.zeros((3, N)), np.zeros(3),
                     np.zeros((2, N)), np.zeros(2), np.empty(N))
    fk.fused_step(basis.copy(), np.zeros((N, 1)), -sym.copy(), sym.copy(), 2 * vn,
                  np.zeros(1), -0.1 * vn, 0.5 * vn, weights, one, -0.5, 0.5)
    use_threads()
    coef = np.zeros((N, 1))
    rows = np.ones((1, N))
    k.projection(sym, np.zeros(N), N, N)
    k.novelty_test(0.5, 1.0, 1e-6, 1e-12, 1e-6)
    k.novelty_margin(0.5, 1.0, 1e-6)
    k.keeps_basis_vectors(1.0, 1e-9)
    rule = np.array([1.0, 1e-6, 1e-12, 1e-6, 1e-9])
    bk.learn_full_expert(basis.copy(), coef.copy(), -sym, sym.copy(), np.zeros(1), 0.5 * vn,
                         -0.1 * vn, 2 * vn, np.ones(1), -0.5, weights, rule, np.empty(N),
                         np.empty(N), np.empty(N))
    terms = np.concatenate([0.5 * vn, -0.1 * vn])  # [k, C k], as an evaluation packs them
    bk.learn_batch(padded([_slab(-sym, sym, coef)], 0), 1, np.zeros(1), terms,
                   np.zeros(1, dtype=np.int64), 2 * rows, np.ones((1, 1)), np.array([-0.5]),
                   weights, rule,
                   np.empty((1, N)), np.empty(1), np.empty(1, dtype=np.int64), np.empty((1, N)),
                   np.empty((1, N)), np.empty(1), np.empty(1, dtype=np.int64), np.empty(1),
                   np.empty(1, dtype=np.bool_), np.zeros(1, dtype=np.int64), 1)


def _warm_evaluation() -> None:
    """The experts evaluated at one input: one at a time, several per call, batched."""
    from roger_daemon.learner.engine import jit_batch as bk
    from roger_daemon.learner.engine import jit_evaluate as ek
    from roger_daemon.learner.engine import jit_kernels as k

    basis, sym = _BASIS, _SYM
    k.kernel_vector(basis, np.zeros(1), 1.0, N)
    k.sym_matvec(sym, np.zeros(N), N, N)
    k.expert_terms(basis, sym, np.zeros((N, 1)), np.zeros(1), 1.0, N, N)
    use_threads()
    width = EVALUATION_WIDTH
    ints = np.full(width, N, dtype=np.int64)

    def pad(array: FloatArray) -> tuple[FloatArray, ...]:
        return padded([array], 0, width)

    slab = _slab(sym, sym, np.zeros((N, 2)))
    args = (pad(slab), 1, ints, np.zeros(1), 1.0, 1.0, 1e-12, True, np.zeros(2 * N + 3),
            np.zeros(width, dtype=np.int64), np.empty((1, 1)), np.empty(1))
    ek.evaluate_experts(*args)
    bk.terms_batch(*args, np.zeros(1, dtype=np.int64), 1)


def _warm_resampling() -> None:
    """The optimal-threshold resampler (paper [15]) and its decision margin."""
    from roger_daemon.learner.engine import jit_resampling as rk

    w, order, _, inv_c, n_top, lse = rk.fearnhead_split(np.log([1.0, 0.5, 0.25]), 2)
    rk.stratified_pass(w, order, n_top, 2, inv_c, 0.5 * inv_c, np.zeros(3), lse, 0.0)
    rk.log_sum_exp(np.zeros(2))
    rk.threshold_taus(np.array([0.5, 0.25]), 2)


def _warm_the_rest() -> None:
    """Copies, the packed helpers, the small experts' kernels, the gates and the lineages; the
    learned transitions' kernels (:mod:`roger_daemon.fsm.jit_fsm`, added to
    :data:`ALSO_WITH_THE_REST` by ``roger compile``: the engine imports nothing above it)."""
    from roger_daemon.learner.engine import jit_batch as bk
    from roger_daemon.learner.engine import jit_cholesky as chk
    from roger_daemon.learner.engine import jit_kernels as k
    from roger_daemon.learner.engine import jit_layout as lk
    from roger_daemon.learner.engine import jit_particles as gk
    from roger_daemon.learner.engine import jit_small as sk
    from roger_daemon.learner.engine import jit_weights as wk

    basis, sym = _BASIS, _SYM
    mat, vn = np.eye(N), np.ones(N)
    k.sym_row(sym, N, N, 1)
    k.min_argmax(np.ones(N))
    k.packed_add_lowrank(sym.copy(), N, N, np.zeros((1, N)), np.zeros(1))
    chk.cholesky_inverse(mat, N, 0.0, np.empty((N, N)))
    chk.cholesky_inverse_logdet(mat, N, 0.0, np.empty((N, N)))
    k.gram_matrix(basis, 1.0, N)
    sk.sparse_update(np.zeros((N, 2)), sym.copy(), N, N, vn, vn, np.zeros(2), -0.5, 0.5)
    sk.shift_mean(np.zeros((N, 2)), np.zeros(1), np.zeros(1), N, 1, np.empty(1))
    sk.novelty_step(sym, np.zeros(N), N, N, 1.0, 1e-3, 1e-12, 1e-6)
    sk.refresh_inverse(basis, 1.0, N, 0.0, sym.copy(), N)
    sk.dot_column(np.zeros(N), np.zeros((N, 2)), 1, N)
    sk.growth_step(basis.copy(), np.zeros((N, 2)), sym.copy(), sym.copy(), N, 1,
                   np.zeros(basis.shape[1]), np.zeros(1), np.zeros(1), np.zeros(2), -0.5, 1.0,
                   1e-3, 1e-12, 1e-6, 1e-9)
    sk.add_basis_vector(basis.copy(), np.zeros((N, 2)), sym.copy(), sym.copy(), N, 1,
                        np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(2), -0.5, 1.0)
    grown = _slab(sym, sym, np.zeros((N, 1)))
    sk.grow_slab(grown, grown.copy(), N)
    slots = np.zeros(1, dtype=np.int64)
    vec, cube = np.ones(1), np.ones((1, 1, 1))
    gk.gate_update(slots, np.zeros(1), np.zeros(1, dtype=np.int64), vec.copy(), 4 * vec,
                   np.zeros((1, 1)), cube.copy(), cube.copy(), vec.copy(), vec.copy(),
                   vec.copy(), vec.copy())
    gk.gate_constants(0.1, 4.0, 0.0, 1)
    gk.gate_log_predictive(slots, np.zeros(1), np.zeros((1, 1)), cube, vec, vec, vec)
    gk.gate_crp_log_terms(slots, np.zeros(1), np.zeros((1, 1)), cube, vec, vec, vec,
                          np.ones(1, dtype=np.int64), np.zeros(1))
    wk.gaussian_log_density(0.0, 1.0, 1)
    wk.slot_log_likelihoods(slots, np.zeros(1), np.zeros((1, 1)), vec, 0.1, 1, np.zeros(1))
    wk.putative_log_weights(np.zeros(2), np.array([0, -1]), np.zeros(1), 0.0)
    gk.trace_lineages(np.zeros((1, 1), dtype=np.int32), np.zeros((1, 1), dtype=np.int64), 1,
                      np.zeros(1, dtype=np.int64))
    gk.lineage_assignments(np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), 1,
                           np.zeros((1, 1), dtype=np.int32), np.zeros((1, 1), dtype=np.int64),
                           1, 0, np.zeros(0, dtype=np.int64), np.zeros((0, 1), dtype=np.int64))
    one, two = np.zeros(1, dtype=np.int64), np.array([0, 1], dtype=np.int64)
    lk.putative_layout(one, two, np.zeros(1), np.zeros(1), 0.0)
    lk.survivor_counts(one, two, one, one, 1)
    lk.survivor_particles(one, two, one, one, one, one, one, 0, one, one)
    use_threads()
    bk.copy_batch(padded([sym], 0), padded([sym.copy()], 0), 1,
                  np.zeros(1, dtype=np.int64), 1)
    bk.balanced_owners(np.array([-1, 0]), np.array([1, 2]), 2, True)
    for warmer in ALSO_WITH_THE_REST:  # kernels of the layers above (roger compile adds them)
        warmer()


#: warmers of compiled kernels outside the learner, run with the rest's family
ALSO_WITH_THE_REST: list[Callable[[], None]] = []

#: the families and what compiling each took on a cold cache, in seconds (2-core AMD EPYC, one
#: process, 2026-11-28: 58 s in all; the learned transitions' kernels 3.8 s more, 2026-12-02 at
#: load 4.8); the costs only balance the shares (:func:`shares`)
WARMERS: tuple[tuple[Callable[[], None], float], ...] = (
    (_warm_learning, 27.6), (_warm_evaluation, 13.8), (_warm_the_rest, 13.5),
    (_warm_resampling, 7.0))


def shares(of: int) -> list[list[Callable[[], None]]]:
    """The families split into ``of`` shares of about equal cost: each family, costliest
    first, goes to the share with the least cost so far (two shares: 27.6 and 30.5 s)."""
    out: list[list[Callable[[], None]]] = [[] for _ in range(of)]
    cost = [0.0] * of
    for warmer, seconds in sorted(WARMERS, key=lambda w: -w[1]):
        least = cost.index(min(cost))
        out[least].append(warmer)
        cost[least] += seconds
    return out


def warm(share: int = 0, of: int = 1) -> None:
    """Compile (or load from numba's cache) the kernels of share ``share`` of ``of``."""
    for warmer in shares(of)[share]:
        warmer()

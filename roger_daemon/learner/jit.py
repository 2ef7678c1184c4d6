"""The learner's compiled kernels (:mod:`.jit_kernels`, :mod:`.jit_fused`, :mod:`.jit_batch`,
:mod:`.jit_particles`, :mod:`.jit_layout`, :mod:`.jit_resampling`, :mod:`.jit_small`,
:mod:`.jit_evaluate`, :mod:`.jit_weights`), loaded on first use.

Importing numba takes about a second, so commands that import the learner without learning
(configuration checks, replay listings, most of the CLI) do not pay it: the first access to a
kernel here imports the modules and binds its functions into this module, so later
accesses are plain attribute lookups.  :func:`warm_up` loads them and compiles every kernel
(or loads it from numba's on-disk cache) before a timed or latency-bound first step.

The batched kernels (:mod:`.jit_batch`) take several experts per call and run them on
:func:`set_threads` threads; :func:`padded` builds their tuples of :data:`WIDTH` experts'
slabs (:mod:`.jit_slab`; :data:`EVALUATION_WIDTH` for the evaluation's).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Sequence
from typing import Any

import numpy.typing as npt

__all__ = ["ADDED", "BATCH_LOCK", "BATCH_MIN_ENTRIES", "DRIFTED", "EVALUATION_WIDTH", "FUSED",
           "KEPT", "KERNELS", "NEEDS_ROOM", "PROJECTED", "SMALL", "WIDTH", "batch_worth",
           "compiled_signatures", "padded", "set_threads", "threads", "use_threads", "warm_up"]

#: up to this many basis vectors ``Q`` is re-inverted by the compiled Cholesky
#: (:func:`.jit_kernels.cholesky_inverse`); above, by LAPACK, which is faster there (2026-11-28,
#: 2-core AMD EPYC: 0.38 against 0.39 ms at 128, 0.81 against 0.71 ms at 200, 2.8 against 1.2
#: ms at 300, docs/performance.md, *A faster compiled re-inversion*).  (Expert evaluation and
#: ``Q k`` are compiled at every size since issue 11's second pass.)
SMALL = 128

#: experts per call of a batched kernel (:mod:`.jit_batch`): their slabs come as a tuple of
#: exactly this many arrays, so each kernel has one compiled signature; at the paper's
#: parameters a step's ~10 updates make one call
WIDTH = 16

#: experts per call of the evaluation's kernels (:func:`.jit_batch.terms_batch`,
#: :func:`.jit_evaluate.evaluate_experts`): a step's ~20 distinct experts at the paper's
#: parameters in one call, so one parallel region.  Each region ends when every thread has
#: finished, and in this project's hosts' slow spells a region costs ~50 µs more than its
#: work (docs/performance.md, *One parallel region for the evaluation*)
EVALUATION_WIDTH = 32

#: below this many packed matrix entries per call (~2 full experts at the paper's beta = 300)
#: the experts go one at a time: a parallel call's start-up then costs more than splitting the
#: work saves (the AIBO stream's ~15-basis-vector experts: docs/performance.md)
BATCH_MIN_ENTRIES = 100_000

#: held while a batched kernel runs: numba's ``workqueue`` threading layer (used where neither
#: TBB nor OpenMP is available) must not be entered by two threads at once
BATCH_LOCK = threading.Lock()

#: :func:`.jit_batch.learn_batch`'s outcome for an expert: the fused step done; not novel
#: (the caller makes the projection update); ``Q`` drifted (the caller re-inverts it first)
FUSED, KEPT, DRIFTED = 0, 1, 2

#: :func:`.jit_small.growth_step`'s outcome for an expert with room for another basis
#: vector: the point added as a basis vector (step 4b); its projection update made (not novel,
#: step 4a); novel but the buffers are full (nothing changed: the caller grows them first).
#: (:data:`DRIFTED`: ``Q`` must be re-inverted first; nothing changed.)
ADDED, PROJECTED, NEEDS_ROOM = 3, 4, 5

_threads: int | None = None  # set_threads(): None until set or first used
_threads_default = True  # set_threads(None) (or never called)
_workqueue = False  # warm_up found numba's threading layer to be workqueue
_applied = threading.local()  # .count: what numba.set_num_threads was given in this thread

KERNELS = ("balanced_owners", "cholesky_inverse", "cholesky_inverse_logdet", "copy_batch",
           "dot_column", "evaluate_expert", "evaluate_experts", "evaluate_slab", "expert_terms",
           "fearnhead_split", "fused_delete_index", "fused_step", "gate_constants",
           "gate_crp_log_terms", "gate_log_predictive", "gate_update", "gaussian_log_density",
           "gram_matrix", "grow_slab", "growth_step", "keeps_basis_vectors", "kernel_vector",
           "learn_batch", "learn_full_expert", "lineage_assignments", "log_sum_exp",
           "min_argmax", "novelty_margin", "novelty_step", "novelty_test",
           "packed_add_lowrank", "projection", "putative_layout", "putative_log_weights",
           "rank_update_cq", "refresh_inverse", "shift_mean", "slab_views",
           "slot_log_likelihoods", "sorted_threshold", "sparse_update", "stratified_pass",
           "survivor_counts", "survivor_particles", "sym_matvec", "sym_matvec_into", "sym_row",
           "terms_batch", "threshold_taus", "trace_lineages")


def _load() -> None:
    from roger_daemon.learner import (
        jit_batch,
        jit_evaluate,
        jit_fused,
        jit_kernels,
        jit_layout,
        jit_particles,
        jit_resampling,
        jit_small,
        jit_weights,
    )

    for module in (jit_kernels, jit_fused, jit_batch, jit_particles, jit_layout, jit_resampling,
                   jit_small, jit_evaluate, jit_weights):
        for name in module.__all__:
            globals()[name] = getattr(module, name)


def __getattr__(name: str) -> Any:
    if name not in KERNELS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    _load()
    return globals()[name]


def padded(arrays: Sequence[npt.NDArray[Any]], start: int, width: int = WIDTH
           ) -> tuple[npt.NDArray[Any], ...]:
    """``arrays[start:start + width]`` as a tuple of exactly ``width`` arrays (:data:`WIDTH`
    or :data:`EVALUATION_WIDTH`), the last one repeated (a batched kernel reads only its
    first ``count``)."""
    chunk = tuple(arrays[start: start + width])
    return chunk + (chunk[-1],) * (width - len(chunk))


def set_threads(count: int | None) -> None:
    """Threads of the batched kernels: ``count`` (capped at numba's ``NUMBA_NUM_THREADS``,
    every core unless that is set), or ``None`` for the default: every core, but one once
    :func:`warm_up` finds numba on its ``workqueue`` threading layer (no TBB, no OpenMP: its
    threads sleep between calls and wake slower than the kernels run).  The results do not
    depend on it (docs/performance.md, *Both cores in one step*)."""
    global _threads, _threads_default
    if count is not None and count < 1:
        raise ValueError(f"threads must be an integer >= 1 or None, got {count!r}")
    import numba

    most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    _threads_default = count is None
    _threads = (1 if _workqueue else most) if count is None else min(int(count), most)
    numba.set_num_threads(_threads)
    _applied.count = _threads


def threads() -> int:
    """The batched kernels' thread count (:func:`set_threads`; the default until set)."""
    if _threads is None:
        set_threads(None)
    assert _threads is not None
    return _threads


def use_threads() -> int:
    """Apply :func:`threads` to the calling thread (numba's count is per thread) and return
    it: called before each learner step's batched kernels."""
    count = threads()
    if getattr(_applied, "count", None) != count:
        import numba

        numba.set_num_threads(count)
        _applied.count = count
    return count


def batch_worth(entries: int) -> bool:
    """Whether experts whose packed matrices hold ``entries`` entries in all should go to a
    batched kernel (several threads and enough work: :data:`BATCH_MIN_ENTRIES`); else each
    expert's kernels are called one at a time, the same floats."""
    return entries >= BATCH_MIN_ENTRIES and use_threads() > 1


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel now, not inside a first step
    (:mod:`.jit_warm`)."""
    from roger_daemon.learner.jit_warm import warm

    _load()
    warm()
    _check_threading_layer()


def _check_threading_layer() -> None:
    """After the first parallel call: on ``workqueue`` the default is one thread."""
    global _workqueue
    import numba

    try:
        _workqueue = numba.threading_layer() == "workqueue"  # type: ignore[attr-defined]
    except ValueError:  # no parallel kernel has run in this process yet
        return
    if _workqueue and _threads_default:
        set_threads(None)


def compiled_signatures(package: str) -> int:
    """How many compiled signatures the numba kernels of ``package`` (``__package__`` for
    this learner, or a reference revision's, :mod:`roger_daemon.bench.reference`) hold in
    this process: after :func:`warm_up`, a count that grows means a kernel was compiled (or
    loaded from numba's cache) inside a learning step."""
    seen: dict[int, int] = {}  # a kernel is bound in its module and here (each counted once)
    for name, module in list(sys.modules.items()):
        if module is None or not (name == package or name.startswith(package + ".")):
            continue
        for obj in vars(module).values():
            if hasattr(obj, "py_func") and hasattr(obj, "signatures"):
                seen[id(obj)] = len(obj.signatures)
    return sum(seen.values())

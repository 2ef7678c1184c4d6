"""The learner's compiled kernels (:mod:`.jit_kernels`, :mod:`.jit_cholesky`, :mod:`.jit_fused`,
:mod:`.jit_batch`, :mod:`.jit_particles`, :mod:`.jit_layout`, :mod:`.jit_resampling`,
:mod:`.jit_small`, :mod:`.jit_evaluate`, :mod:`.jit_weights`), loaded on first use.

Importing numba takes about a second, so commands that import the learner without learning
(configuration checks, replay listings, most of the CLI) do not pay it: the first access to a
kernel here imports the modules and binds its functions into this module, so later
accesses are plain attribute lookups.  :func:`warm_up` loads them and compiles every kernel
(or loads it from numba's on-disk cache) before a timed or latency-bound first step.

Also handed on from here: the constants the kernels are compiled with
(:mod:`.jit_constants`) and the batched kernels' thread count (:mod:`.jit_threads`).
"""

from __future__ import annotations

import sys
from typing import Any

from roger_daemon.learner.engine.jit_constants import (
    ADDED,
    DRIFTED,
    EVALUATION_WIDTH,
    FUSED,
    KEPT,
    NEEDS_ROOM,
    PROJECTED,
    SMALL,
    WIDTH,
    padded,
)
from roger_daemon.learner.engine.jit_threads import (
    BATCH_LOCK,
    BATCH_MIN_ENTRIES,
    batch_worth,
    check_threading_layer,
    set_threads,
    threads,
    use_threads,
)

__all__ = ["ADDED", "BATCH_LOCK", "BATCH_MIN_ENTRIES", "DRIFTED", "EVALUATION_WIDTH", "FUSED",
           "KEPT", "KERNELS", "NEEDS_ROOM", "PROJECTED", "SMALL", "WIDTH", "batch_worth",
           "compiled_signatures", "load", "padded", "set_threads", "threads", "use_threads",
           "warm_up"]

KERNELS = ("add_basis_vector", "balanced_owners", "cholesky_inverse", "cholesky_inverse_logdet",
           "cholesky_lower", "copy_batch", "dot_column", "evaluate_expert", "evaluate_experts",
           "evaluate_slab",
           "expert_terms", "fearnhead_split", "fused_delete_index", "fused_step", "gate_constants",
           "gate_crp_log_terms", "gate_log_predictive", "gate_update", "gaussian_log_density",
           "gram_matrix", "grow_slab", "growth_step", "keeps_basis_vectors", "kernel_vector",
           "learn_batch", "learn_full_expert", "lineage_assignments", "log_sum_exp",
           "lower_inverse_transposed", "min_argmax",
           "novelty_margin", "novelty_step", "novelty_test", "packed_add_lowrank", "projection",
           "putative_layout", "putative_log_weights", "rank_update_cq", "refresh_inverse",
           "shift_mean", "slab_views", "slot_log_likelihoods", "sorted_threshold", "sparse_update",
           "stratified_pass", "survivor_counts", "survivor_particles", "sym_matvec",
           "sym_matvec_into", "sym_row", "terms_batch", "threshold_taus", "trace_lineages")


def load() -> None:
    """Import every kernel module and bind its kernels here (done on first access)."""
    from roger_daemon.learner.engine import (
        jit_batch,
        jit_cholesky,
        jit_evaluate,
        jit_fused,
        jit_kernels,
        jit_layout,
        jit_particles,
        jit_resampling,
        jit_small,
        jit_weights,
    )

    for module in (jit_kernels, jit_cholesky, jit_fused, jit_batch, jit_particles, jit_layout,
                   jit_resampling, jit_small, jit_evaluate, jit_weights):
        for name in module.__all__:
            globals()[name] = getattr(module, name)


def __getattr__(name: str) -> Any:
    if name not in KERNELS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    load()
    return globals()[name]


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel now, not inside a first step
    (:mod:`.jit_warm`); then the default thread count follows numba's threading layer
    (:func:`.jit_threads.check_threading_layer`)."""
    from roger_daemon.learner.engine.jit_warm import warm

    load()
    warm()
    check_threading_layer()


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

"""The learner's compiled kernels (:mod:`.jit_kernels`, :mod:`.jit_fused`,
:mod:`.jit_particles`, :mod:`.jit_resampling`), loaded on first use.

Importing numba takes about a second, so commands that import the learner without learning
(configuration checks, replay listings, most of the CLI) do not pay it: the first access to a
kernel here imports the four modules and binds its functions into this module, so later
accesses are plain attribute lookups.  :func:`warm_up` loads them and compiles every kernel
(or loads it from numba's on-disk cache) before a timed or latency-bound first step.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

__all__ = ["KERNELS", "SMALL", "compiled_signatures", "warm_up"]

#: up to this many basis vectors ``Q`` is re-inverted by the compiled Cholesky
#: (:func:`.jit_kernels.cholesky_inverse`); above, by LAPACK.  (Expert evaluation and ``Q k``
#: are compiled at every size since issue 11's second pass.)
SMALL = 64

KERNELS = ("cholesky_inverse", "expert_terms", "fearnhead_split",
           "fused_delete_index", "fused_step",
           "gate_log_predictive", "gate_update", "gram_matrix", "kernel_vector", "min_argmax",
           "packed_add_lowrank",
           "rank_update_cq", "sorted_threshold", "stratified_pass", "sym_matvec", "sym_matvec_into",
           "sym_row", "threshold_taus", "trace_lineages")


def _load() -> None:
    from roger_daemon.learner import jit_fused, jit_kernels, jit_particles, jit_resampling

    for module in (jit_kernels, jit_fused, jit_particles, jit_resampling):
        for name in module.__all__:
            globals()[name] = getattr(module, name)


def __getattr__(name: str) -> Any:
    if name not in KERNELS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    _load()
    return globals()[name]


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel now, not inside a first step."""
    from roger_daemon.learner import jit_fused as fk
    from roger_daemon.learner import jit_kernels as k
    from roger_daemon.learner import jit_particles as gk
    from roger_daemon.learner import jit_resampling as rk

    _load()
    n = 2
    basis = np.zeros((n, 1))
    mat = np.eye(n)
    sym = np.array([1.0, 0.0, 1.0])  # the identity, packed (:mod:`.packed`)
    k.kernel_vector(basis, np.zeros(1), 1.0, n)
    k.sym_matvec(sym, np.zeros(n), n, n)
    k.sym_row(sym, n, n, 1)
    k.min_argmax(np.ones(n))
    k.packed_add_lowrank(sym.copy(), n, n, np.zeros((1, n)), np.zeros(1))
    k.expert_terms(basis, sym, np.zeros((n, 1)), np.zeros(1), 1.0, n, n)
    k.rank_update_cq(sym.copy(), sym.copy(), n, n, 0, np.zeros((3, n)), np.zeros(3),
                     np.zeros((2, n)), np.zeros(2), np.empty(n))
    k.cholesky_inverse(mat, n, 0.0, np.empty((n, n)))
    vn, one, weights = np.ones(n), np.ones(1), np.ones(1)
    weights.setflags(write=False)  # as sogp_fused passes them: read-only, its own signature
    fk.fused_step(basis.copy(), np.zeros((n, 1)), -sym.copy(), sym.copy(), 2 * vn,
                  np.zeros(1), -0.1 * vn, 0.5 * vn, weights, one, -0.5, 0.5)
    k.gram_matrix(basis, 1.0, n)
    slots = np.zeros(1, dtype=np.int64)
    vec, cube = np.ones(1), np.ones((1, 1, 1))
    gk.gate_update(slots, np.zeros(1), vec.copy(), vec.copy(), np.zeros((1, 1)), cube.copy(),
                  cube.copy(), vec.copy())
    gk.gate_log_predictive(slots, np.zeros(1), np.zeros((1, 1)), cube, vec, vec, vec)
    gk.trace_lineages(np.zeros((1, 1), dtype=np.int32), np.zeros((1, 1), dtype=np.int64), 1,
                     np.zeros(1, dtype=np.int64))
    w, order, _, inv_c, n_top = rk.fearnhead_split(np.array([1.0, 0.5, 0.25]), 1.75, 2)
    rk.stratified_pass(w, order, n_top, 2, inv_c, 0.5 * inv_c, np.zeros(3), 0.0, 0.0)
    rk.threshold_taus(np.array([0.5, 0.25]), 2)  # the resampler's decision margin


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

"""The fastest an exact learner step could be on this machine, with no Python and both cores
(issue 11, docs/performance.md, *An exact step on both cores, measured*).

A ROGER step at the paper's parameters evaluates every distinct expert version (``k``,
``C k``, ``k^T C k``: one pass over its packed ``C``) and then updates the chosen versions
(``Q k``, then the rank-3 update of ``C`` and rank-2 update of ``Q``: a read-and-write pass
over each).  This script runs exactly those passes, with the learner's own compiled kernels
(:func:`~roger_daemon.learner.engine.jit_kernels.expert_terms`,
:func:`~roger_daemon.learner.engine.jit_kernels.sym_matvec`,
:func:`~roger_daemon.learner.engine.jit_fused.rank_update_cq`), inside one compiled call per step,
first on one thread and then split over ``--threads`` threads (numba ``prange``: the
evaluations in parallel, then the updates in parallel), over as many ``beta x beta`` versions
as the benchmark stream has, whose basis vectors have its perception's dimension (23; until
2026-11-28 the default was 3, which left out most of the kernel vectors' cost).  Nothing else
of a step (gates, resampling, bookkeeping, a full expert's basis vector deleted) is counted, so
the rate it prints is an upper bound for any exact step that makes these passes over packed
float64 matrices (each version's ``C`` read, each updated ``C`` and ``Q`` read and written),
as the learner's does.

Two figures say how far those kernels are from the machine (docs/performance.md, *How close the
kernels are to the machine*): ``bytes_only_ms_per_step``, the same bytes read and written by
the simplest loops that touch them (a sum, a scaling: the floor for any kernel that moves them,
whatever its arithmetic), and the evaluations' ``C k`` by the learner's kernel against
OpenBLAS's packed symmetric product (``dspmv``), both on one thread.

    .venv/bin/python scripts/learner_parallel_bound.py [--versions 20] [--updated 10]
        [--beta 300] [--dim 23] [--steps 2000] [--threads 2] [--json]
"""

from __future__ import annotations

import argparse
import itertools
import time
from collections.abc import Callable

import numba
import numpy as np
from numba import prange
from scipy.linalg import blas
from threadpoolctl import threadpool_limits

from roger_daemon.bench.learner import print_report
from roger_daemon.learner.engine import jit_fused, jit_kernels, packed
from roger_daemon.learner.engine.jit_compile import compiled
from roger_daemon.learner.synthetic import BENCH_D_X
from roger_daemon.machine import finish, machine_record

FloatArray = np.ndarray


@compiled(parallel=True, nogil=True)  # cached: the CLI and its test compile it once
def exact_step_passes(bases: FloatArray, cs: FloatArray, qs: FloatArray, coefs: FloatArray,
                      x: FloatArray, gamma: float, n: int, updated: np.ndarray,
                      scale: float) -> float:
    """One step's matrix passes: every version evaluated, then the ``updated`` ones updated
    (a tiny symmetric rank-3 / rank-2 update, so the matrices stay what they were)."""
    versions = cs.shape[0]
    kck = np.zeros(versions)
    ks = np.zeros((versions, n))
    cks = np.zeros((versions, n))
    for v in prange(versions):
        terms = jit_kernels.expert_terms(bases[v], cs[v], coefs[v], x, gamma, n, n)
        kck[v] = terms[2 * n]
        ks[v] = terms[:n]
        cks[v] = terms[n: 2 * n]
    for u in prange(updated.shape[0]):
        v = updated[u]
        qk = jit_kernels.sym_matvec(qs[v], ks[v], n, n)
        uc = np.empty((3, n))
        uc[0] = cks[v]
        uc[1] = qk
        uc[2] = ks[v]
        uq = np.empty((2, n))
        uq[0] = qk
        uq[1] = ks[v]
        cc = np.array([scale, -scale, scale])
        cq = np.array([scale, -scale])
        jit_fused.rank_update_cq(cs[v], qs[v], n, n, -1, uc, cc, uq, cq, np.empty(n))
    return float(kck.sum())


@compiled(parallel=True, nogil=True, fastmath=True)  # a floor, not a result: any order will do
def bytes_only_passes(cs: FloatArray, qs: FloatArray, updated: np.ndarray) -> float:
    """The bytes of :func:`exact_step_passes` with the least work per byte: every version's
    ``C`` summed, then each updated version's ``Q`` summed and its ``C`` and ``Q`` scaled in
    place by 1 (read and written)."""
    versions = cs.shape[0]
    sums = np.zeros(versions + updated.shape[0])
    for v in prange(versions):
        c = cs[v]
        t = 0.0
        for j in range(c.shape[0]):
            t += c[j]
        sums[v] = t
    for u in prange(updated.shape[0]):
        c = cs[updated[u]]
        q = qs[updated[u]]
        t = 0.0
        for j in range(q.shape[0]):
            t += q[j]
        for j in range(q.shape[0]):
            q[j] *= 1.0
            c[j] *= 1.0
        sums[versions + u] = t
    return float(sums.sum())


@compiled(nogil=True)
def learner_products(cs: FloatArray, ks: FloatArray, n: int, out: FloatArray) -> None:
    """``out[v] = C_v k_v`` for every version by the learner's kernel, one thread."""
    for v in range(cs.shape[0]):
        jit_kernels.sym_matvec_into(cs[v], ks[v], n, n, out[v])


def openblas_products(cs: FloatArray, ks: FloatArray, n: int) -> FloatArray:
    """The same products by OpenBLAS's ``dspmv``: the learner's packed rows (``S[i, i:]``,
    row-major) are BLAS's lower packed columns."""
    return np.array([blas.dspmv(n, 1.0, c, k, lower=1) for c, k in zip(cs, ks, strict=True)])


def versions_like_the_learner(count: int, beta: int, dim: int, rng: np.random.Generator,
                              dtype: type = np.float64) -> tuple[FloatArray, ...]:
    """``count`` full versions: a basis, a packed SPD ``C``-like and ``Q``-like matrix
    (stored as ``dtype``), one output column."""
    size = packed.packed_size(beta)
    bases = rng.uniform(-1.0, 1.0, (count, beta, dim))
    cs: FloatArray = np.empty((count, size), dtype=dtype)
    qs: FloatArray = np.empty((count, size), dtype=dtype)
    for v in range(count):
        a = rng.standard_normal((beta, beta)) / beta
        spd = a @ a.T + np.eye(beta)
        cs[v] = packed.pack(-spd, beta)
        qs[v] = packed.pack(spd, beta)
    coefs = rng.standard_normal((count, beta, 1))
    return bases, cs, qs, coefs


def per_step_ms(threads: int, data: tuple[FloatArray, ...], steps: int, updated: int,
                gamma: float, rng: np.random.Generator) -> float:
    """Milliseconds per step with ``threads`` numba threads (median of five blocks, after one
    untimed step that compiles the call)."""
    numba.set_num_threads(threads)
    bases, cs, qs, coefs = data
    versions, beta, dim = bases.shape
    xs = rng.uniform(-1.0, 1.0, (steps, dim))
    chosen = [np.sort(rng.choice(versions, updated, replace=False)) for _ in range(steps)]
    step = itertools.cycle(range(steps))  # each call the next step's point and versions

    def one_step() -> float:
        s = next(step)
        return exact_step_passes(bases, cs, qs, coefs, xs[s], gamma, beta, chosen[s], 1e-12)

    return median_ms(one_step, steps)


def median_ms(call: Callable[[], object], repeats: int) -> float:
    """Milliseconds per ``call()``: the median of five blocks of ``repeats // 5`` calls, after
    one untimed call."""
    call()
    block = max(1, repeats // 5)
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(block):
            call()
        times.append((time.perf_counter() - t0) / block * 1e3)
    return float(np.median(times))


def kernel_distance(threads: int, data: tuple[FloatArray, ...], steps: int, updated: int,
                    rng: np.random.Generator) -> dict[str, float]:
    """How far the passes are from the machine: the bytes-only floor on ``threads`` threads,
    and the evaluations' ``C k`` by the learner's kernel and by OpenBLAS (one thread)."""
    bases, cs, qs, _ = data
    versions, n = bases.shape[:2]
    chosen = np.sort(rng.choice(versions, updated, replace=False))
    numba.set_num_threads(threads)
    floor = median_ms(lambda: bytes_only_passes(cs, qs, chosen), steps)
    ks = rng.uniform(0.0, 1.0, (versions, n))
    ours = np.empty((versions, n))
    cs64 = cs.astype(np.float64, copy=False)
    mine = median_ms(lambda: learner_products(cs64, ks, n, ours), steps)
    theirs = median_ms(lambda: openblas_products(cs64, ks, n), steps)
    gap = float(np.max(np.abs(ours - openblas_products(cs64, ks, n)))
                / max(float(np.max(np.abs(ours))), 1e-300))
    return {f"bytes_only_ms_per_step_{threads}_threads": round(floor, 3),
            "evaluations_ck_ms_learner_kernel": round(mine, 3),
            "evaluations_ck_ms_openblas_dspmv": round(theirs, 3),
            "learner_vs_openblas_max_rel_diff": float(f"{gap:.2e}")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--versions", type=int, default=20)
    parser.add_argument("--updated", type=int, default=10)
    parser.add_argument("--beta", type=int, default=300)
    parser.add_argument("--dim", type=int, default=BENCH_D_X,
                        help=f"the basis vectors' dimension (default {BENCH_D_X}: the "
                             "benchmark stream's perception)")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--float32", action="store_true",
                        help="store C and Q in float32 (arithmetic stays float64): what halving "
                             "the bytes would buy; not exact (docs/performance.md)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    for name in ("versions", "beta", "dim", "steps", "threads"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1 (got {getattr(args, name)})")
    if not 0 <= args.updated <= args.versions:
        parser.error(f"--updated must be between 0 and --versions (got {args.updated})")
    machine = machine_record()
    rng = np.random.default_rng(0)
    data = versions_like_the_learner(args.versions, args.beta, args.dim, rng,
                                     np.float32 if args.float32 else np.float64)
    with threadpool_limits(1):
        one = per_step_ms(1, data, args.steps, args.updated, 1.0, rng)
        many = per_step_ms(args.threads, data, args.steps, args.updated, 1.0, rng)
        distance = kernel_distance(args.threads, data, args.steps, args.updated, rng)
    out = {
        "versions": args.versions, "updated_per_step": args.updated, "beta": args.beta,
        "dim": args.dim,
        "storage": "float32" if args.float32 else "float64",
        "threads": args.threads, "threading_layer": numba.threading_layer(),  # type: ignore[attr-defined]
        "one_thread_ms_per_step": round(one, 3),
        "one_thread_updates_per_s_bound": round(1e3 / one, 1),
        f"{args.threads}_threads_ms_per_step": round(many, 3),
        f"{args.threads}_threads_updates_per_s_bound": round(1e3 / many, 1),
        "speed_up": round(one / many, 2),
        **distance,
        "machine": finish(machine),
    }
    print_report(out, as_json=args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

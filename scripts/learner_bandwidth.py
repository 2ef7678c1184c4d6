"""How far the learner step is from the memory bandwidth bound (issue 11, docs/fleet.md).

Counts the passes over the experts' ``beta x beta`` symmetric matrices (``C`` and ``Q``, stored
packed: their upper triangles, :mod:`roger_daemon.learner.engine.packed`) that one ROGER step
makes on the benchmark stream (``roger bench learner``: paper parameters), measures how fast this
machine streams such a matrix when the experts do not fit in the core's cache (cycling over as
many distinct matrices as the step touches) and when one matrix stays cached, and prints the
time those passes alone take per step.

    .venv/bin/python scripts/learner_bandwidth.py [--points 1500] [--json]
"""

from __future__ import annotations

import argparse
import inspect
import time
from collections import Counter
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from roger_daemon.bench.learner import learned_model, print_report
from roger_daemon.learner.engine import jit, packed


def count_passes(points: int) -> tuple[dict[str, float], float, int, int]:
    """Compiled calls per step by kind, measured ms per step, distinct experts, beta.

    The learner runs on one thread, where it evaluates the experts several per call
    (``jit.evaluate_experts``, each counted as one ``expert_terms`` pass) and updates each
    one from Python (on several threads it batches both,
    :mod:`roger_daemon.learner.engine.jit_batch`): the same passes.  A full
    expert's ``jit.learn_full_expert`` counts as its ``Q k`` pass and, when it made one, its
    fused step; ``jit.growth_step`` (an expert that is not full: its ``Q k`` and novelty
    test, then a rank-1 update) and ``jit.novelty_step`` as its ``Q k`` pass."""
    jit.set_threads(1)
    warm = points // 4
    model, stream = learned_model(warm)
    calls: Counter[str] = Counter()
    jit.load()
    kinds = ("evaluate_experts", "expert_terms", "projection", "novelty_step", "growth_step",
             "fused_step", "learn_full_expert")
    originals = {name: getattr(jit, name) for name in kinds}
    # where evaluate_experts takes its number of experts (found by name: a reordered
    # signature must not count another argument)
    count_at = list(inspect.signature(jit.evaluate_experts.py_func).parameters).index("count")

    def counted(name: str, fn: Any) -> Any:
        def wrapper(*args: Any) -> Any:
            out = fn(*args)
            if name == "evaluate_experts":  # several experts' C k passes in one call
                calls["expert_terms"] += args[count_at]
            elif name in ("novelty_step", "growth_step"):  # an expert's Q k, novelty test
                calls["projection"] += 1
            elif name != "learn_full_expert":
                calls[name] += 1
            else:  # a full expert's Q k and, for a novel point, its fused step
                calls["projection"] += 1
                calls["fused_step"] += out[0] == jit.FUSED
            return out
        return wrapper

    for name, fn in originals.items():
        setattr(jit, name, counted(name, fn))
    try:
        t0 = time.perf_counter()
        for i in range(warm, points):
            model.learn_one(stream.x[i], stream.y[i])
        ms = (time.perf_counter() - t0) / (points - warm) * 1e3
    finally:
        for name, fn in originals.items():
            setattr(jit, name, fn)
    steps = points - warm
    return ({k: v / steps for k, v in calls.items()}, ms, model.n_unique_experts,
            model.params.beta)


def stream_us(mats: list[np.ndarray], n: int, repeats: int) -> float:
    """Microseconds per ``sym_matvec`` pass over a packed ``n x n`` matrix, cycling over
    ``mats``."""
    v = np.ones(n)
    jit.sym_matvec(mats[0], v, n, n)
    t0 = time.perf_counter()
    for _ in range(repeats):
        for m in mats:
            jit.sym_matvec(m, v, n, n)
    return (time.perf_counter() - t0) / (repeats * len(mats)) * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1500)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.points < 8:
        parser.error(f"--points must be at least 8 (got {args.points})")
    with threadpool_limits(1):
        per_step, step_ms, unique, beta = count_passes(args.points)
        rng = np.random.default_rng(0)
        size = packed.packed_size(beta)
        mats = [rng.standard_normal(size) for _ in range(3 * unique)]  # C, Q (and K_B's room)
        cold = stream_us(mats, beta, 50)
        hot = stream_us(mats[:1], beta, 2000)
    mb = packed.packed_size(beta) * 8 / 1e6
    # a C k or Q k pass reads one matrix; the fused step reads and writes C and Q
    reads = per_step.get("expert_terms", 0.0) + per_step.get("projection", 0.0)
    rw = 2 * per_step.get("fused_step", 0.0)
    bound_ms = (reads * cold + rw * 2 * cold) / 1e3
    out = {
        "beta": beta, "distinct_experts": unique, "step_ms": round(step_ms, 3),
        "passes_per_step": {k: round(v, 2) for k, v in per_step.items()},
        "matrix_mb": round(mb, 3),
        "pass_us_out_of_cache": round(cold, 1), "pass_us_in_cache": round(hot, 1),
        "gb_per_s_out_of_cache": round(mb / cold * 1e3, 1),
        "passes_ms_per_step": round(bound_ms, 3),
        "updates_per_s_at_that_bound": round(1e3 / bound_ms, 1),
    }
    print_report(out, as_json=args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

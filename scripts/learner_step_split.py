"""Where a learner step's time goes on this host, sampled over time (issue 11,
docs/performance.md, *The slow spells are the two cores far apart*).

The benchmark's step (``roger bench learner``: the synthetic stream at the paper's
parameters) is timed in two parts: the experts' compiled kernels (the evaluation and the
update: :func:`~roger_daemon.learner.engine.jit_batch.terms_batch`,
:func:`~roger_daemon.learner.engine.jit_batch.learn_batch`,
:func:`~roger_daemon.learner.engine.jit_batch.copy_batch` and their one-expert-at-a-time forms)
and everything else (Python, numpy and the small compiled calls of the gates, resampling and
bookkeeping).  Each sample restores the model learned to ``--warm-points`` pairs (the
benchmark's timed window starts at 2,500), learns the next ``--steps`` pairs on every core,
then the same pairs on one thread, then times the speed probe
(:func:`roger_daemon.machine.speed_probe`) and the cross-core round trip
(:func:`roger_daemon.machine.cross_core_ns`).  Samples repeat for ``--minutes``: this
project's hosts have spells in which the kernels slow down and the Python does not, which the
speed probe does not see and the round trip does (the two vCPUs on cores far apart); the
split shows which part moved.

    .venv/bin/python scripts/learner_step_split.py [--minutes 2] [--steps 800]
        [--warm-points 2500] [--pause 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

from roger_daemon.bench.learner import learned_model, load_stream
from roger_daemon.learner import Roger
from roger_daemon.learner.engine import jit as lazy_jit
from roger_daemon.learner.synthetic import BENCH_SEED
from roger_daemon.machine import cross_core_ns, finish, machine_record, speed_probe

#: the experts' kernels (evaluation, update, copies), batched and one expert at a time
EXPERT_KERNELS = ("terms_batch", "learn_batch", "copy_batch", "evaluate_experts",
                  "learn_full_expert")


class KernelClock:
    """Wraps :data:`EXPERT_KERNELS` in :mod:`roger_daemon.learner.engine.jit` (this process only)
    and adds up the nanoseconds spent in them."""

    def __init__(self) -> None:
        lazy_jit.warm_up()
        self.ns = 0
        for name in EXPERT_KERNELS:
            setattr(lazy_jit, name, self._timed(getattr(lazy_jit, name)))

    def _timed(self, kernel: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any) -> Any:
            start = time.perf_counter_ns()
            try:
                return kernel(*args)
            finally:
                self.ns += time.perf_counter_ns() - start
        return call


def timed_steps(clock: KernelClock, state: dict[str, Any], x: Any, y: Any, start: int,
                steps: int, threads: int) -> tuple[float, float]:
    """``(step_us, kernel_us)``, means over ``steps`` pairs learned from the restored
    ``state`` on ``threads`` threads."""
    lazy_jit.set_threads(threads)
    model = Roger.from_state_dict(state)
    clock.ns = 0
    t0 = time.perf_counter_ns()
    for i in range(start, start + steps):
        model.learn_one(x[i], y[i])
    total = time.perf_counter_ns() - t0
    return total / steps / 1e3, clock.ns / steps / 1e3


def sample(clock: KernelClock, state: dict[str, Any], x: Any, y: Any, start: int,
           steps: int, cores: int) -> dict[str, Any]:
    """One sample: every core, one thread, the speed probe, the cross-core round trip."""
    out: dict[str, Any] = {"time": time.strftime("%H:%M:%S")}
    for label, threads in (("all_cores", cores), ("one_thread", 1)):
        step_us, kernel_us = timed_steps(clock, state, x, y, start, steps, threads)
        out[label] = {"step_us": round(step_us, 1), "kernel_us": round(kernel_us, 1),
                      "other_us": round(step_us - kernel_us, 1)}
    out["speed_probe"] = speed_probe(repeats=1)
    out["cross_core_ns"] = cross_core_ns()
    return out


def summary(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """Minimum, median and maximum of each part over the samples."""
    out: dict[str, Any] = {}
    for label in ("all_cores", "one_thread"):
        for part in ("step_us", "kernel_us", "other_us"):
            values = [s[label][part] for s in samples]
            out[f"{label}_{part}"] = {"min": min(values), "median": statistics.median(values),
                                      "max": max(values)}
    return out


def _line(s: dict[str, Any]) -> str:
    a, o, p = s["all_cores"], s["one_thread"], s["speed_probe"]
    return (f"{s['time']}  all cores: step {a['step_us']:7.1f} us = kernels {a['kernel_us']:6.1f}"
            f" + other {a['other_us']:6.1f}  |  one thread: step {o['step_us']:7.1f} = kernels "
            f"{o['kernel_us']:6.1f} + other {o['other_us']:6.1f}  |  probe Python "
            f"{p['python_ms']} ms, memory {p['memory_ms']} ms  |  cross-core "
            f"{s['cross_core_ns']} ns")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=2.0,
                        help="keep sampling this long (default 2; 0: one sample)")
    parser.add_argument("--steps", type=int, default=800, help="pairs per timing (default 800)")
    parser.add_argument("--warm-points", type=int, default=2500,
                        help="pairs learned before the timed ones (default 2500)")
    parser.add_argument("--pause", type=float, default=3.0,
                        help="seconds between samples (default 3)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    for name, value, least in (("--minutes", args.minutes, 0.0), ("--steps", args.steps, 1),
                               ("--warm-points", args.warm_points, 1),
                               ("--pause", args.pause, 0.0)):
        if value < least:
            parser.exit(2, f"{parser.prog}: error: {name} must be >= {least} "
                           f"(got {value})\n")
    length = load_stream("synthetic", None, BENCH_SEED, []).x.shape[0]
    if length < args.warm_points + args.steps:
        parser.exit(2, f"{parser.prog}: error: --warm-points + --steps must be at most "
                       f"{length} (got {args.warm_points + args.steps})\n")
    record = machine_record()
    clock = KernelClock()
    cores = lazy_jit.threads()
    model, stream = learned_model(args.warm_points)
    state = model.state_dict()
    samples: list[dict[str, Any]] = []
    end = time.monotonic() + 60.0 * args.minutes
    while True:
        samples.append(sample(clock, state, stream.x, stream.y, args.warm_points, args.steps,
                              cores))
        if not args.json:
            print(_line(samples[-1]), flush=True)
        if time.monotonic() + args.pause >= end:
            break
        time.sleep(args.pause)
    report = {"steps_per_timing": args.steps, "warm_points": args.warm_points,
              "cores": cores, "samples": samples, "summary": summary(samples),
              "machine": finish(record)}
    if args.json:
        json.dump(report, sys.stdout, indent=1)
        print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

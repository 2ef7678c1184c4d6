"""``roger bench learner --compare REF``: this learner and revision REF's, side by side.

Both models learn the same stream in one process, one update of each in turn (REF's, then
this one's, for every pair), so both see the same machine load at the same moment; each update
is timed on its own.  REF's learner comes from git (:mod:`.reference`).  Reported per
implementation: updates/s, update p50/p99; then ``speedup`` = this updates/s / REF's, and
whether both ended with the same segmentation (MAP assignments) and the largest difference of
their final predictions (a float change in the learner shows up there).
"""

from __future__ import annotations

import importlib
import time
from types import ModuleType
from typing import Any

import numpy as np

from roger_daemon.bench.learner import NOTE, BenchStream, _ms
from roger_daemon.bench.reference import load_reference
from roger_daemon.learner import Roger
from roger_daemon.learner.engine.jit import compiled_signatures, threads, warm_up
from roger_daemon.machine import describe, finish, machine_record

__all__ = ["compare", "compare_table", "reference_kernels"]


def _summary(samples: list[int]) -> dict[str, float]:
    return {"updates_per_s": round(len(samples) / (float(np.sum(samples)) * 1e-9), 1),
            "update_p50_ms": _ms(samples, 50), "update_p99_ms": _ms(samples, 99)}


def reference_kernels(ref_pkg: ModuleType) -> ModuleType | None:
    """The reference learner's kernel facade: ``engine.jit`` (since issue 58), ``jit`` before;
    ``None`` for a revision from before the compiled kernels."""
    for where in ("engine.jit", "jit"):
        try:
            return importlib.import_module(f"{ref_pkg.__name__}.{where}")
        except ModuleNotFoundError:
            continue
    return None


def _warm_up_reference(ref_pkg: ModuleType) -> None:
    """Compile (or load from numba's cache) the reference's kernels before timing: a kernel
    first used mid-run (the fused step, once experts are full) would otherwise put its
    compilation, seconds for a revision not seen before, into the reference's time.  A
    reference with batched kernels runs them on this learner's threads (``--threads``)."""
    ref_jit = reference_kernels(ref_pkg)
    if ref_jit is None:  # a revision from before the compiled kernels
        return
    same_threads = getattr(ref_jit, "set_threads", None)
    if callable(same_threads):  # a revision with batched kernels: on this learner's threads
        same_threads(threads())
    warm = getattr(ref_jit, "warm_up", None)
    if callable(warm):
        warm()


def compare(stream: BenchStream, rev: str, seed: int) -> dict[str, Any]:
    """Learn ``stream`` with revision ``rev``'s Roger and this Roger, interleaved."""
    machine = machine_record()
    ref_pkg, sha = load_reference(rev)
    points, d_x = stream.x.shape
    d_y = stream.y.shape[1]
    # nu0 resolved for the stream (older revisions have no d_x + 1 default)
    ref_params = ref_pkg.RogerParams.from_mapping(stream.params.for_dims(d_x).to_mapping())
    warm_up()
    _warm_up_reference(ref_pkg)
    for model in (ref_pkg.Roger(d_x, d_y, ref_params, seed=seed),
                  Roger(d_x, d_y, stream.params, seed=seed)):  # any compilation, untimed
        for i in range(min(3, points)):
            model.learn_one(stream.x[i], stream.y[i])
    ref = ref_pkg.Roger(d_x, d_y, ref_params, seed=seed)
    new = Roger(d_x, d_y, stream.params, seed=seed)
    t_ref: list[int] = []
    t_new: list[int] = []
    clock = time.perf_counter_ns
    packages = (ref_pkg.__name__, Roger.__module__.rsplit(".", 1)[0])
    before = [compiled_signatures(p) for p in packages]
    for i in range(points):
        x, y = stream.x[i], stream.y[i]
        t0 = clock()
        ref.learn_one(x, y)
        t1 = clock()
        new.learn_one(x, y)
        t2 = clock()
        t_ref.append(t1 - t0)
        t_new.append(t2 - t1)
    a, b = _summary(t_ref), _summary(t_new)
    compiled = [compiled_signatures(p) - n for p, n in zip(packages, before, strict=True)]
    probe = stream.x[-1]
    pa, pb = ref.predict_one(probe), new.predict_one(probe)
    finish(machine)
    return {
        "bench": "learner-compare",
        "stream": stream.name,
        "points": points,
        "ref": {"rev": rev, "sha": sha, **a, "experts": ref.n_experts},
        "new": {"rev": "working tree", **b, "experts": new.n_experts},
        "speedup": round(b["updates_per_s"] / a["updates_per_s"], 2),
        "same_segmentation": bool(np.array_equal(ref.assignments(), new.assignments())),
        "prediction_max_abs_diff": float(np.max(np.abs(pa.mean - pb.mean))),
        # kernels compiled inside the timed steps (a signature first met mid-run): then the
        # figures include compilation, and a second run (numba's cache filled) is the one
        "compiled_while_timing": {"ref": compiled[0], "new": compiled[1]},
        "learner_threads": threads(),  # both learners' batched kernels (a reference's if it has)
        "seed": seed,
        "params": stream.params.to_mapping(),
        "machine": machine,
        "note": NOTE,
    }


def compare_table(res: dict[str, Any]) -> str:
    """The comparison as an aligned text table."""
    ref, new = res["ref"], res["new"]
    rows = [("", f"REF {ref['rev']} ({ref['sha'][:10]})", "new (working tree)")]
    for key, label in (("updates_per_s", "updates/s (mean)"), ("update_p50_ms", "update p50 ms"),
                       ("update_p99_ms", "update p99 ms"), ("experts", "experts (MAP)")):
        rows.append((label, str(ref[key]), str(new[key])))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    lines = [f"{r[0]:<{w0}}  {r[1]:<{w1}}  {r[2]}" for r in rows]
    m = res["machine"]
    lines += [
        f"stream {res['stream']}, {res['points']} points, one update of each in turn",
        f"speedup (new / REF updates/s): {res['speedup']}x",
        f"same segmentation: {res['same_segmentation']}; final prediction max |diff|: "
        f"{res['prediction_max_abs_diff']:.3g}",
        f"machine: {describe(m)}",
        *([f"kernel signatures first met while timing: REF {res['compiled_while_timing']['ref']}"
           f", new {res['compiled_while_timing']['new']} (each compiled, or loaded from numba's"
           " cache, inside a timed step; against a revision not run before, run it again)"]
          if any(res["compiled_while_timing"].values()) else []),
    ]
    return "\n".join(lines)

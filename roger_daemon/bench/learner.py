"""``roger bench learner``: learner throughput and latency on a shipped stream.

``--stream synthetic`` (default, :func:`roger_daemon.learner.synthetic.subtask_stream`): 4,000
points, 23-D inputs, 9-D outputs and 4 subtasks with overlapping inputs, with the paper's
parameters.  ``--stream aibo``: the first 1,500 pairs of the goal-scoring experiment's AIBO
demonstrations (``roger_daemon/bench/data``), with the daemon's default configuration (the
``default`` preset and the AIBO profile).  ``--param`` overrides a parameter of either.  Every
update is timed; every ``--predict-every`` steps ``predict_multimap``, ``predict_one`` and
``predict_with_multimap`` (both in one pass, the daemon's call) are timed on the next input.
The unimap baseline learns the same stream in the same run. On a 23-D/9-D stream the learned
transitions' update (after every step) and choice (at every timed prediction) are timed beside
the step (:mod:`.transitions`; ``transitions`` in the JSON, ``--no-transitions`` skips them).
``--compare REF`` runs git revision REF's learner beside this one instead
(:mod:`.learner_compare`).  ``--json`` prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.console import UsageError
from roger_daemon.learner import Roger, RogerParams, UnimapGP
from roger_daemon.learner.engine.jit import set_threads, threads, warm_up
from roger_daemon.learner.params import ParameterError
from roger_daemon.learner.synthetic import BENCH_SEED, subtask_stream
from roger_daemon.machine import describe, finish, machine_record

_AIBO = Path(__file__).with_name("data") / "aibo-demonstrations.npz"
STREAMS = ("synthetic", "aibo")

__all__ = ["BenchStream", "configure", "load_stream", "measure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger bench learner``."""
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--stream", choices=STREAMS, default="synthetic",
                        help="synthetic: 4,000 points, paper parameters (default); aibo: 1,500 "
                             "AIBO demonstration pairs, the daemon's default configuration")
    parser.add_argument("--points", type=int, default=None,
                        help="points learned (default: the whole stream)")
    parser.add_argument("--seed", type=int, default=0, help="model seed (default 0)")
    parser.add_argument("--stream-seed", type=int, default=BENCH_SEED,
                        help=f"stream seed (default {BENCH_SEED}, the shipped stream)")
    parser.add_argument("--predict-every", type=int, default=10,
                        help="time the predictions every K updates (default 10)")
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                        help="override a RogerParams field (VALUE as JSON), repeatable")
    parser.add_argument("--no-unimap", action="store_true", help="skip the unimap baseline")
    parser.add_argument("--no-transitions", action="store_true",
                        help="skip timing the learned transitions (roger+fsm's update and "
                             "roger play's choice) beside the step")
    parser.add_argument("--threads", type=int, default=None, metavar="N",
                        help="threads of the learner's batched kernels (default: every core; "
                             "the results do not depend on it)")
    parser.add_argument("--compare", metavar="REF", default=None,
                        help="instead, time git revision REF's learner (e.g. main, HEAD~3) "
                             "and this one in this process, one update of each in turn on the "
                             "same stream, and print both and the speed ratio (needs the git "
                             "checkout)")


@dataclass(frozen=True)
class BenchStream:
    """A benchmark stream and the parameters it is learned with."""

    name: str
    x: np.ndarray
    y: np.ndarray
    labels: np.ndarray
    params: RogerParams


def load_stream(name: str, points: int | None, stream_seed: int,
                overrides: list[str]) -> BenchStream:
    """The named stream (first ``points`` pairs) with its base parameters and ``overrides``."""
    if name == "aibo":
        from roger_daemon.config import parse_config

        with np.load(_AIBO) as data:
            x, y, labels = data["x"], data["y"], data["labels"].astype(np.int64)
        base = parse_config({}).robots[0].params  # the daemon's default for the AIBO
    else:
        stream = subtask_stream(4000 if points is None else points, seed=stream_seed)
        x, y, labels, base = stream.x, stream.y, stream.labels, RogerParams()
    n = x.shape[0] if points is None else min(points, x.shape[0])
    return BenchStream(name, x[:n], y[:n], labels[:n], _params(base, overrides))


def _params(base: RogerParams, overrides: list[str]) -> RogerParams:
    mapping: dict[str, Any] = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            raise UsageError(f"--param needs KEY=VALUE, got {item!r}")
        try:
            mapping[key] = json.loads(value)
        except json.JSONDecodeError:
            mapping[key] = value
    try:
        return RogerParams.from_mapping({**base.to_mapping(), **mapping})
    except ParameterError as exc:
        raise UsageError(f"--param: {exc}") from None


def learned_model(points: int, seed: int = 0,
                  on_step: Callable[[Roger, int], None] | None = None
                  ) -> tuple[Roger, BenchStream]:
    """A ROGER model that learned the first ``points`` pairs of the benchmark's synthetic
    stream (paper parameters), and the stream: the state the diagnostic scripts inspect
    (``scripts/learner_bandwidth.py``, ``scripts/learner_shared_base.py``); ``on_step(model,
    i)`` is called after the ``i``-th pair."""
    stream = load_stream("synthetic", None, BENCH_SEED, [])
    model = Roger(stream.x.shape[1], stream.y.shape[1], stream.params, seed=seed)
    for i in range(points):
        model.learn_one(stream.x[i], stream.y[i])
        if on_step is not None:
            on_step(model, i)
    return model, stream


def print_report(out: dict[str, Any], *, as_json: bool) -> None:
    """A diagnostic script's result, with the load average now: one JSON object, or one
    aligned ``key value`` line per entry."""
    out = {**out, "load_avg_1m": os.getloadavg()[0]}
    if as_json:
        print(json.dumps(out))
        return
    width = max(map(len, out)) + 2
    for key, val in out.items():
        print(f"{key:{width}s}{val}")


NOTE = ("wall-clock timings on a shared machine: other processes compete for the cores "
        "(see machine.load_avg_*) and its speed drifts (machine.speed_probe)")


def _ms(samples: list[int], q: float) -> float:
    return round(float(np.percentile(np.asarray(samples) * 1e-6, q)), 3) if samples else 0.0


def _purity(assign: np.ndarray, labels: np.ndarray) -> float:
    """Share of points whose expert's majority subtask is their own subtask."""
    good = 0
    for e in np.unique(assign):
        good += int(np.bincount(labels[assign == e]).max())
    return good / max(1, labels.size)


def _ari(a: np.ndarray, b: np.ndarray) -> float:
    """Adjusted Rand index of two labelings (Hubert & Arabie 1985)."""
    _, ai = np.unique(a, return_inverse=True)
    _, bi = np.unique(b, return_inverse=True)
    table = np.zeros((ai.max() + 1, bi.max() + 1))
    np.add.at(table, (ai, bi), 1)

    def comb2(v: np.ndarray) -> float:
        return float(np.sum(v * (v - 1) / 2))

    index = comb2(table)
    ra, rb, n = comb2(table.sum(1)), comb2(table.sum(0)), comb2(np.array([a.size]))
    expected = ra * rb / n if n else 0.0
    top = 0.5 * (ra + rb)
    return 1.0 if top == expected else (index - expected) / (top - expected)


def measure(stream: BenchStream, seed: int, stream_seed: int, predict_every: int,
            unimap: bool, transitions: bool = True) -> dict[str, Any]:
    """Run the benchmark and return the result object."""
    machine = machine_record()
    params = stream.params
    points, d_x = stream.x.shape
    d_y = stream.y.shape[1]
    warm_up()
    model = Roger(d_x, d_y, params, seed=seed)
    timer = None
    if transitions and (d_x, d_y) == (23, 9):  # the AIBO's memory layout (roger+fsm)
        from roger_daemon.bench.transitions import TransitionTimer

        timer = TransitionTimer()
    upd: list[int] = []
    pm: list[int] = []
    po: list[int] = []
    pw: list[int] = []
    clock = time.perf_counter_ns
    start = time.perf_counter()
    for i in range(points):
        t0 = clock()
        model.learn_one(stream.x[i], stream.y[i])
        upd.append(clock() - t0)
        if timer is not None:
            timer.after_update(model, stream.x[i], stream.y[i])
        if predict_every > 0 and i % predict_every == 0:
            q = stream.x[min(i + 1, points - 1)]
            t0 = clock()
            model.predict_multimap(q)
            pm.append(clock() - t0)
            t0 = clock()
            model.predict_one(q)
            po.append(clock() - t0)
            t0 = clock()
            model.predict_with_multimap(q)  # the daemon's one call per tick
            pw.append(clock() - t0)
            if timer is not None:
                timer.at_tick(q)
    wall = time.perf_counter() - start
    upd_arr = np.asarray(upd) * 1e-9
    quarters = [round(len(c) / float(c.sum()), 1) for c in np.array_split(upd_arr, 4) if c.size]
    assign = model.assignments()
    out: dict[str, Any] = {
        "bench": "learner",
        "stream": stream.name,
        "points": points,
        "d_x": d_x,
        "d_y": d_y,
        "subtasks": int(stream.labels.max()) + 1,
        "updates_per_s": round(points / float(upd_arr.sum()), 1),
        "updates_per_s_by_quarter": quarters,
        "update_p50_ms": _ms(upd, 50),
        "update_p99_ms": _ms(upd, 99),
        "update_max_ms": _ms(upd, 100),
        "predict_multimap_p50_ms": _ms(pm, 50),
        "predict_multimap_p99_ms": _ms(pm, 99),
        "predict_one_p99_ms": _ms(po, 99),
        "predict_with_multimap_p99_ms": _ms(pw, 99),
        "experts": model.n_experts,
        "expert_sizes": sorted(model.expert_sizes().values(), reverse=True),
        "unique_experts": model.n_unique_experts,
        "particles": model.n_particles,
        "max_basis_vectors": max(model.basis_sizes().values(), default=0),
        "segmentation_purity": round(_purity(assign, stream.labels), 3),
        "segmentation_ari": round(_ari(assign, stream.labels), 3),
        "roger_wall_s": round(wall, 2),
        "learner_threads": threads(),
    }
    if timer is not None:
        timer.play(model)
        out["transitions"] = timer.result(upd)
    if unimap:
        base = UnimapGP(d_x, d_y, params, seed=seed)
        uni: list[int] = []
        for i in range(points):
            t0 = clock()
            base.learn_one(stream.x[i], stream.y[i])
            uni.append(clock() - t0)
        out["unimap_updates_per_s"] = round(points / (float(np.sum(uni)) * 1e-9), 1)
        out["unimap_update_p99_ms"] = _ms(uni, 99)
    out["seed"] = seed
    out["stream_seed"] = stream_seed
    out["params"] = params.to_mapping()
    out["machine"] = finish(machine)
    out["note"] = NOTE
    return out


def _table(res: dict[str, Any]) -> str:
    rows = [
        ("stream, points", f"{res['stream']}, {res['points']}"),
        ("updates/s (mean)", res["updates_per_s"]),
        ("updates/s by quarter", res["updates_per_s_by_quarter"]),
        ("update p50 / p99 / max ms",
         f"{res['update_p50_ms']} / {res['update_p99_ms']} / {res['update_max_ms']}"),
        ("predict_multimap p50 / p99 ms",
         f"{res['predict_multimap_p50_ms']} / {res['predict_multimap_p99_ms']}"),
        ("predict_one p99 ms", res["predict_one_p99_ms"]),
        ("predict_with_multimap p99 ms", res["predict_with_multimap_p99_ms"]),
        ("experts (MAP particle)", res["experts"]),
        ("expert sizes", res["expert_sizes"][:12]),
        ("unique experts / particles", f"{res['unique_experts']} / {res['particles']}"),
        ("max basis vectors", res["max_basis_vectors"]),
        ("learner threads", res["learner_threads"]),
        ("segmentation purity / ARI",
         f"{res['segmentation_purity']} / {res['segmentation_ari']}"),
    ]
    tr = res.get("transitions")
    if tr is not None:
        rows.append(("transitions update p50 / p99 ms",
                     f"{tr['update_p50_ms']} / {tr['update_p99_ms']} "
                     f"({100 * tr['update_share_of_step']:.1f} % of the mean step)"))
        if "tick_p50_ms" in tr:
            rows.append(("transitions tick p50 / p99 ms",
                         f"{tr['tick_p50_ms']} / {tr['tick_p99_ms']} "
                         f"({100 * tr['tick_share_of_step']:.1f} % of the mean step)"))
    if "unimap_updates_per_s" in res:
        rows.append(("unimap updates/s, p99 ms",
                     f"{res['unimap_updates_per_s']}, {res['unimap_update_p99_ms']}"))
    m = res["machine"]
    rows.append(("machine", describe(m)))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def run(args: argparse.Namespace) -> int:
    """Run ``roger bench learner``."""
    if args.points is not None and args.points < 1:
        print("--points must be >= 1", file=sys.stderr)
        return 2
    if args.threads is not None and args.threads < 1:
        raise UsageError(f"--threads must be an integer >= 1, got {args.threads}")
    set_threads(args.threads)
    stream = load_stream(args.stream, args.points, args.stream_seed, args.param)
    if args.compare is not None:
        from roger_daemon.bench.learner_compare import compare, compare_table
        from roger_daemon.bench.reference import RevisionError

        try:
            res = compare(stream, args.compare, args.seed)
        except RevisionError as exc:
            raise UsageError(f"--compare: {exc}") from None
        print(json.dumps(res) if args.json else compare_table(res))
        return 0
    res = measure(stream, args.seed, args.stream_seed, args.predict_every, not args.no_unimap,
                  not args.no_transitions)
    print(json.dumps(res) if args.json else _table(res))
    return 0

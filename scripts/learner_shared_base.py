"""How far a shared base per expert would cut a learner step's memory traffic (issue 11).

On the benchmark stream (``roger bench learner``: paper parameters) the distinct experts are
the particles' versions of a few experts (docs/performance.md). This learns the stream up to
``--points``, groups the live versions by expert id, takes one version of each group as the
base and measures, for every other version, the numerical rank of ``C_v - C_base`` and
``Q_v - Q_base`` (eigenvalues above ``--tol`` times the largest magnitude). It then times the
read a step makes for the GP likelihood of every version (``k^T C k``): one pass over each
version's packed ``C`` (what the learner does now), against one pass over each base plus a
thin correction per version (``k^T C_base k + sum_i d_i (u_i . k)^2``). The floats of the two
agree to rounding (printed); nothing in the learner changes.

The split above is numerical: a base and a correction of low *numerical* rank, found by an
eigendecomposition, not an exact representation the learner could keep. An exact one would
store, per version, the updates it received since the common ancestor of all the versions of
its expert (each a rank-3 correction of ``C``). ``--genealogy`` (default on) follows every
update and copy while learning and reports, at every step after the first third, how many
updates each version received since that common ancestor: the length such an exact
correction would have.

    .venv/bin/python scripts/learner_shared_base.py [--points 1500] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import time
from collections import defaultdict
from collections.abc import Iterator
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from roger_daemon.bench.learner import learned_model, print_report
from roger_daemon.learner import roger_step, sogp
from roger_daemon.learner.engine import jit, packed


def low_rank(delta: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(U, d)`` with ``delta ~= U diag(d) U^T`` keeping eigenvalues above ``tol * max``."""
    w, v = np.linalg.eigh((delta + delta.T) / 2)
    big = np.abs(w) > tol * max(float(np.max(np.abs(w))), 1e-300)
    return np.ascontiguousarray(v[:, big].T), w[big]


def versions(points: int) -> tuple[dict[int, list[Any]], np.ndarray]:
    """The live SOGP versions grouped by expert id, after ``points`` points; a query x."""
    model, stream = learned_model(points)
    groups: dict[int, list[Any]] = defaultdict(list)
    store = model.store
    for slot in store.live().tolist():
        if store.expert(slot).n > 1:
            groups[int(store.ids[slot])].append(store.expert(slot))
    return groups, stream.x[points]


_STEP_UPDATES = "update_evaluated"  # the function a ROGER step updates its chosen experts with


class Genealogy:
    """Each live SOGP's updates, as a tuple of tokens shared with the versions it was copied
    from, and per step the updates since each expert's versions' common ancestor."""

    def __init__(self) -> None:
        self.updates: dict[int, tuple[int, ...]] = {}  # id(gp) -> update tokens, oldest first
        self.counter = itertools.count()
        self.since: list[int] = []  # per version and step: updates since the common ancestor
        self.batched = False  # inside the step's batched update, which counts its experts itself

    def updated(self, gp: Any) -> None:
        self.updates[id(gp)] = (*self.updates.get(id(gp), ()), next(self.counter))

    def step(self, model: Any, i: int, first: int) -> None:
        if i < first:
            return
        groups: dict[int, list[tuple[int, ...]]] = defaultdict(list)
        store = model.store
        for slot in store.live().tolist():
            groups[int(store.ids[slot])].append(self.updates.get(id(store.expert(slot)), ()))
        for hist in groups.values():
            common = 0
            while all(len(h) > common for h in hist) and len({h[common] for h in hist}) == 1:
                common += 1
            self.since.extend(len(h) - common for h in hist)


@contextlib.contextmanager
def following(gen: Genealogy) -> Iterator[None]:
    """Record every SOGP update and copy (the learner's own methods, wrapped) into ``gen``."""
    cls = sogp.SparseOnlineGP
    init, update, copy = cls.__init__, cls.update, cls.copy
    many = getattr(roger_step, _STEP_UPDATES)

    def init_(self: Any, *a: Any, **k: Any) -> None:
        init(self, *a, **k)
        gen.updates[id(self)] = ()

    def update_(self: Any, *a: Any, **k: Any) -> None:
        if not gen.batched:
            gen.updated(self)
        update(self, *a, **k)

    def copy_(self: Any, *a: Any, **k: Any) -> Any:
        out = copy(self, *a, **k)
        gen.updates[id(out)] = gen.updates.get(id(self), ())
        return out

    def many_(gps: Any, *a: Any, **k: Any) -> None:  # one ROGER step's updates
        for gp in gps:
            gen.updated(gp)
        gen.batched = True
        try:
            many(gps, *a, **k)
        finally:
            gen.batched = False

    cls.__init__, cls.update, cls.copy = init_, update_, copy_  # type: ignore[method-assign]
    setattr(roger_step, _STEP_UPDATES, many_)
    try:
        yield
    finally:
        cls.__init__, cls.update, cls.copy = init, update, copy  # type: ignore[method-assign]
        setattr(roger_step, _STEP_UPDATES, many)


def genealogy(points: int) -> dict[str, Any]:
    """Updates each version received since its expert's common ancestor (steps after the
    first third of ``points``)."""
    gen = Genealogy()
    with following(gen):
        learned_model(points, on_step=lambda m, i: gen.step(m, i, points // 3))
    since = np.asarray(gen.since)
    return {"updates_since_common_ancestor_p50_p90_max":
            [int(np.median(since)), int(np.percentile(since, 90)), int(since.max())]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1500)
    parser.add_argument("--tol", type=float, default=1e-13)
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--no-genealogy", dest="genealogy", action="store_false",
                        help="skip the updates-since-the-common-ancestor count (a second run)")
    args = parser.parse_args()
    if args.points < 30:
        parser.error(f"--points must be at least 30 (got {args.points})")
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1 (got {args.repeats})")
    with threadpool_limits(1):
        groups, x = versions(args.points)
        dense, bases, thin, ranks_c, ranks_q, errs = [], [], [], [], [], []
        for gps in groups.values():
            base = gps[0]
            n = base.n
            bases.append(base.C)  # unpacked (n x n)
            for gp in gps:
                if gp.n != n:  # a version of another size: kept dense
                    dense.append(gp.C)
                    continue
                c = gp.C
                dense.append(c)
                u, d = low_rank(c - bases[-1], args.tol)
                ranks_c.append(len(d))
                ranks_q.append(len(low_rank(gp.Q - base.Q, args.tol)[1]))
                thin.append((len(bases) - 1, u, d))
                k = np.exp(-0.1 * np.sum((gp._B[:n] - x) ** 2, axis=1))
                exact = float(k @ c @ k)
                approx = float(k @ bases[-1] @ k + np.sum(d * (u @ k) ** 2))
                errs.append(abs(exact - approx) / max(abs(exact), 1e-300))
        k = np.ones(max(m.shape[0] for m in dense))
        # timed as the learner stores them: packed upper triangles (learner.packed)
        dense_p = [(packed.pack(m, m.shape[0]), m.shape[0]) for m in dense]
        bases_p = [(packed.pack(m, m.shape[0]), m.shape[0]) for m in bases]

        def run_dense() -> None:
            for m, n in dense_p:
                jit.sym_matvec(m, k, n, n)

        def run_shared() -> None:
            for m, n in bases_p:
                jit.sym_matvec(m, k, n, n)
            for _, u, d in thin:
                np.sum(d * (u @ k[:u.shape[1]]) ** 2)

        out: dict[str, Any] = {"points": args.points, "versions": len(dense),
                               "experts": len(groups)}
        for name, fn in (("dense", run_dense), ("shared", run_shared)):
            fn()
            t0 = time.perf_counter()
            for _ in range(args.repeats):
                fn()
            out[f"{name}_us_per_step"] = round((time.perf_counter() - t0) / args.repeats * 1e6, 1)
    out.update({
        "rank_c_p50_max": [int(np.median(ranks_c)), int(max(ranks_c))] if ranks_c else None,
        "rank_q_p50_max": [int(np.median(ranks_q)), int(max(ranks_q))] if ranks_q else None,
        "kck_relative_error_max": float(max(errs)) if errs else None,
    })
    if args.genealogy:
        with threadpool_limits(1):
            out.update(genealogy(args.points))
    print_report(out, as_json=args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

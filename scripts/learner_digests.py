"""SHA-256 digests of what the learner learns on the shipped streams: the proof that a change to
the learner's code changed no float.

Three runs, each a :class:`~roger_daemon.learner.Roger` model (seed 0) learning a stream from
the first pair on, then answering a few queries:

* ``synthetic``: ``roger bench learner``'s stream (4,000 pairs) with the paper's parameters;
* ``aibo``: ``roger bench learner --stream aibo`` (1,500 AIBO demonstration pairs) with the
  daemon's default configuration (the ``default`` preset, the AIBO profile);
* ``levers``: the synthetic stream (1,500 pairs) with most levers away from the paper's
  values (a prior mean per expert, stickiness, pruning, Grollman's kernel and normaliser,
  input weights, scaling, a small ``beta`` so that the experts fill up, sampled predictions
  with the empty expert).

For each run: ``state``, the digest of the model's ``state_dict`` (:func:`.checkpoint.array_digest`,
the checkpoints' own), and ``answers``, the digest of its MAP assignments and of
``predict_table`` at the next 25 inputs (means, variances, gate probabilities, expert ids).
The ``synthetic`` run also learns the unimap baseline (``unimap``).  Equal digests before and
after a change: the same learned bits on this host (the digests of another host may differ:
docs/reproducibility.md).

    .venv/bin/python scripts/learner_digests.py [--points N] [--json]

``--points`` cuts every stream short (a quick check; the full streams take ~10 s).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from roger_daemon.bench.learner import BenchStream, load_stream
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.learner import Roger, UnimapGP
from roger_daemon.learner.synthetic import BENCH_SEED

#: the ``levers`` run's parameters: most of the levers of issue 13 and the fidelity switches on
LEVERS = ["gp_prior_mean=expert", "sticky_kappa=2.0", "min_support=5", "prune_log_margin=30",
          "likelihood_normaliser=grollman", "kernel_dim_scaling=grollman", "theta_w=0.5",
          "novelty_threshold=1e-4", "beta=40", "predict_empty_expert=true",
          "expert_choice=sample", "y_offset=[0.1,0,0,0,0,0,0,0,-0.1]",
          "x_scale=" + json.dumps([1.0] * 20 + [2.0, 2.0, 2.0]),
          "input_weights=" + json.dumps([1.0] * 21 + [0.0, 0.5])]
RUNS = {"synthetic": ("synthetic", 4000, []), "aibo": ("aibo", 1500, []),
        "levers": ("synthetic", 1500, LEVERS)}
QUERIES = 25


def _answers_digest(model: Roger | UnimapGP, queries: np.ndarray) -> str:
    """SHA-256 of the MAP assignments and ``predict_table`` at every query (in order)."""
    h = hashlib.sha256(np.ascontiguousarray(model.assignments()).tobytes())
    for q in queries:
        pred, table = model.predict_table(q)
        for arr in (pred.mean, pred.var, table.means, table.variances,
                    np.asarray(table.gate_probs, dtype=np.float64),
                    np.asarray(table.expert_ids + table.n_points + [pred.expert_id],
                               dtype=np.int64)):
            h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def learned(stream: BenchStream, points: int, model: Roger | UnimapGP) -> dict[str, Any]:
    """``model`` after learning the first ``points`` pairs of ``stream``: its digests."""
    for i in range(points):
        model.learn_one(stream.x[i], stream.y[i])
    state = array_digest(model.state_dict())  # before any prediction draws
    queries = stream.x[points: points + QUERIES]
    if queries.shape[0] == 0:
        queries = stream.x[-QUERIES:]
    return {"state": state, "answers": _answers_digest(model, queries),
            "points": points, "experts": model.n_experts}


def digests(points: int | None = None, runs: Sequence[str] = tuple(RUNS),
            seed: int = 0) -> dict[str, dict[str, Any]]:
    """The digests of every run in ``runs`` (each stream cut to ``points`` pairs if given)."""
    out: dict[str, dict[str, Any]] = {}
    for name in runs:
        stream_name, length, overrides = RUNS[name]
        n = length if points is None else min(points, length)
        stream = load_stream(stream_name, n + QUERIES, BENCH_SEED, overrides)
        n = min(n, stream.x.shape[0])
        d_x, d_y = stream.x.shape[1], stream.y.shape[1]
        out[name] = learned(stream, n, Roger(d_x, d_y, stream.params, seed=seed))
        if name == "synthetic":
            out["unimap"] = learned(stream, n, UnimapGP(d_x, d_y, stream.params, seed=seed))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the digests (one line per run, or one JSON object)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=None,
                        help="cut every stream to N pairs (default: the whole streams)")
    parser.add_argument("--seed", type=int, default=0, help="the models' seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.points is not None and args.points < 1:
        parser.exit(2, f"{parser.prog}: error: --points must be >= 1 (got {args.points})\n")
    got = digests(args.points, seed=args.seed)
    if args.json:
        print(json.dumps(got, sort_keys=True))
        return 0
    for name, d in got.items():
        print(f"{name:10s} state {d['state'][:16]}  answers {d['answers'][:16]}  "
              f"({d['points']} pairs, {d['experts']} experts)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

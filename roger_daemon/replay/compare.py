"""Compare models by behaviour: expert count and sizes, assignments, predictions on probes.

Two models that learned the same pairs in the same order with the same params and seed behave
identically, but their ``state_dict()`` arrays may not be byte-equal (slot layout, buffer
growth), so recovery and regression tests compare :func:`behaviour` instead. The result is
JSON-ready (lists and floats), so it also serves as the golden output of a replay.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["ABS_FLOOR", "REL_TOL", "behaviour", "behaviour_differences", "max_abs_diff",
           "probe_inputs", "rel_err"]

#: Two runs of the learner on different BLAS kernels (``OPENBLAS_CORETYPE``) or CPUs agree to
#: this relative error on every float they publish; the structure (experts, ids, sizes,
#: assignments, labels, chosen expert) is compared exactly. Measured margin and the rule:
#: docs/reproducibility.md.
REL_TOL = 1e-5
#: Below this magnitude a float is compared absolutely (a relative error of ~0 means nothing).
ABS_FLOOR = 1e-12


def _arrays(a: Any, b: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """Both as float64 arrays, or ``None`` if their shapes differ."""
    x = np.asarray(a, dtype=np.float64)
    y = np.asarray(b, dtype=np.float64)
    return (x, y) if x.shape == y.shape else None


def max_abs_diff(a: Any, b: Any) -> float:
    """``max|a - b|`` (0 for empty arrays; ``inf`` if the shapes differ or the result is NaN)."""
    xy = _arrays(a, b)
    if xy is None:
        return math.inf
    if xy[0].size == 0:
        return 0.0
    d = float(np.max(np.abs(xy[0] - xy[1])))
    return d if not math.isnan(d) else math.inf


def rel_err(a: Any, b: Any) -> float:
    """Normwise relative error ``max|a - b| / (max(max|a|, max|b|) + ABS_FLOOR)``.

    0 for bit-identical arrays; ``inf`` if the shapes differ or a value is NaN or infinite in
    one and not the other. Normwise (the array's largest magnitude as the scale), because a
    component of an action vector passing through 0 carries the round-off of the whole
    computation (docs/reproducibility.md).
    """
    xy = _arrays(a, b)
    if xy is None:
        return math.inf
    x, y = xy
    if x.size == 0:
        return 0.0
    same = (x == y) | (np.isnan(x) & np.isnan(y))
    if same.all():
        return 0.0
    if not (np.isfinite(x[~same]).all() and np.isfinite(y[~same]).all()):
        return math.inf
    scale = max(float(np.max(np.abs(x[np.isfinite(x)]), initial=0.0)),
                float(np.max(np.abs(y[np.isfinite(y)]), initial=0.0)))
    return float(np.max(np.abs(x[~same] - y[~same]))) / (scale + ABS_FLOOR)


def _floats(v: Any) -> list[float]:
    return [float(a) for a in np.asarray(v, dtype=np.float64).reshape(-1)]


def behaviour(model: Any, probes: Sequence[Any]) -> dict[str, Any]:
    """What a model does: ``n_learned``, ``n_experts``, ``expert_sizes``, ``assignments`` and,
    for every probe input, ``predict_one`` and ``predict_multimap``."""
    out: dict[str, Any] = {
        "n_learned": int(model.n_learned),
        "n_experts": int(model.n_experts),
        "expert_sizes": {str(k): int(v) for k, v in sorted(dict(model.expert_sizes()).items())},
        "assignments": [int(a) for a in np.asarray(model.assignments()).reshape(-1)],
        "probes": [],
    }
    for x in probes:
        p, mm = model.predict_with_multimap(np.asarray(x, dtype=np.float64))
        out["probes"].append({
            "x": _floats(x),
            "mean": _floats(p.mean),
            "var": _floats(p.var),
            "expert": int(p.expert_id),
            "multimap": [{"expert": int(e.expert_id), "p": float(e.gate_prob),
                          "mean": _floats(e.mean), "var": _floats(e.var),
                          "n": int(e.n_points)} for e in mm],
        })
    return out


def behaviour_differences(a: Mapping[str, Any], b: Mapping[str, Any],
                          tol: float = REL_TOL) -> list[str]:
    """What differs between two :func:`behaviour` results (empty: the same structure, and
    every float within relative error ``tol``, :func:`rel_err`)."""
    diffs: list[str] = []
    for key in ("n_learned", "n_experts", "expert_sizes"):
        if a[key] != b[key]:
            diffs.append(f"{key}: {a[key]} != {b[key]}")
    if a["assignments"] != b["assignments"]:
        n = next((i for i, (x, y) in enumerate(zip(a["assignments"], b["assignments"],
                                                   strict=False)) if x != y),
                 min(len(a["assignments"]), len(b["assignments"])))
        diffs.append(f"assignments differ from pair {n} on "
                     f"({len(a['assignments'])} vs {len(b['assignments'])} pairs)")
    if len(a["probes"]) != len(b["probes"]):
        diffs.append(f"{len(a['probes'])} probes vs {len(b['probes'])}")
        return diffs
    for i, (p, q) in enumerate(zip(a["probes"], b["probes"], strict=True)):
        if rel_err(p["x"], q["x"]) > 0:
            diffs.append(f"probe {i}: different inputs")
            continue
        for key in ("mean", "var"):
            d = rel_err(p[key], q[key])
            if d > tol:
                diffs.append(f"probe {i}: {key} differs by relative {d:.3g}")
        if p["expert"] != q["expert"]:
            diffs.append(f"probe {i}: expert {p['expert']} != {q['expert']}")
        ids_p = [e["expert"] for e in p["multimap"]]
        ids_q = [e["expert"] for e in q["multimap"]]
        if ids_p != ids_q:
            diffs.append(f"probe {i}: multimap experts {ids_p} != {ids_q}")
            continue
        for e, f in zip(p["multimap"], q["multimap"], strict=True):
            d = max(rel_err(e["p"], f["p"]), rel_err(e["mean"], f["mean"]),
                    rel_err(e["var"], f["var"]))
            if d > tol or e["n"] != f["n"]:
                diffs.append(f"probe {i}: expert {e['expert']} differs by relative {d:.3g} "
                             f"(n {e['n']} vs {f['n']})")
    return diffs


def probe_inputs(xs: Sequence[Any], n: int = 12) -> list[list[float]]:
    """About ``n`` probe inputs: rows of ``xs`` spread over the stream, plus midpoints of
    neighbouring picks (inputs the model never saw); deterministic."""
    arr = np.asarray(xs, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if len(arr) == 0:
        return []
    k = max(1, (n + 1) // 2)
    idx = np.unique(np.linspace(0, len(arr) - 1, k).round().astype(int))
    picks = [arr[i] for i in idx]
    mids = [(picks[i] + picks[i + 1]) / 2 for i in range(len(picks) - 1)]
    out = [p for p in picks] + mids
    return [[float(v) for v in r] for r in out[:n]]

"""Helpers for ``state_dict``: flat named arrays plus JSON metadata, never pickle.

A state dict is ``dict[str, np.ndarray]`` with numeric arrays only, plus ``"meta"``: a 0-d
unicode array holding a JSON object (schema version, model kind, dimensions, parameters,
random-generator states, counters).  ``np.savez`` and ``np.load(allow_pickle=False)`` round-trip
it unchanged.  Layout (schema 5):

* ``expert_*``: the U distinct experts, concatenated: ``expert_n_bv`` (U,), ``expert_n_points``
  (U,), ``expert_alloc`` (U,), ``expert_B`` (sum n, d_m), ``expert_A`` (sum n, d_y, or d_y + 1
  with ``gp_prior_mean = "expert"``: the ``a1`` column last), ``expert_mean`` (U, d_y, the GP
  prior means), ``expert_C`` and ``expert_Q`` (sum n^2, row-major blocks),
  ``expert_diag_cache`` (sum n);
* ROGER only: ``expert_id``, ``expert_count`` (CRP counts), ``gate_*`` (the NIW statistics and
  cached predictive of each expert), ``particle_log_weights`` (P,), ``particle_offsets`` (P+1,)
  and ``particle_experts`` (indices into the experts, per particle in order),
  ``history_settled`` (M,), the expert id of each settled point (-1 at an exception),
  ``history_exception_points`` (K,) and ``history_exception_ids`` (K, P), the points on which
  the lineages still disagree and each boundary particle's id there, and ``history_ancestor`` /
  ``history_expert`` (N - M, P, one row when saved), each survivor's ancestor and chosen expert
  at the later steps, for :meth:`~.roger.Roger.assignments` (:mod:`.history`).

Everything that influences future results is stored (including caches), so a restored model
continues bit-identically.

Migration: schema 1 (before the issue-13 levers) had no ``expert_mean``;
the means are read as zeros,
and its params lack the new fields, which take their defaults (the paper's, all levers off), so
a schema-1 state loads as the same model.  Schema 2 kept the whole (N, P) history and no
``history_settled``, schema 3 a prefix settled where all lineages met and every row after it,
no exceptions; both load as the same history, settled on load.  Schemas 2-4 also stored
``expert_K`` (``K_B``), which is ignored: the learner recomputes ``K_B`` from the basis vectors
to the same floats (:func:`.jit_kernels.gram_matrix`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.sogp import SparseOnlineGP

__all__ = [
    "SCHEMA_VERSION",
    "generator_from_state",
    "generator_state",
    "model_meta",
    "pack_experts",
    "pack_meta",
    "unpack_experts",
    "unpack_meta",
]

SCHEMA_VERSION = 5
# 1: before the GP prior mean; 2: the full history; 3: no exceptions; 4: K_B stored (all
# migrated on load)
READABLE_SCHEMAS = (1, 2, 3, 4, 5)

def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return {"__ndarray__": value.tolist(), "dtype": str(value.dtype)}
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, np.integer):
        return int(value)
    return value


def _from_jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        if "__ndarray__" in value:
            return np.asarray(value["__ndarray__"], dtype=value["dtype"])
        return {k: _from_jsonable(v) for k, v in value.items()}
    return value


def generator_state(gen: np.random.Generator) -> dict[str, Any]:
    """The bit generator's state as JSON-able data (name included)."""
    out: dict[str, Any] = _jsonable(gen.bit_generator.state)
    return out


def generator_from_state(state: Mapping[str, Any]) -> np.random.Generator:
    """Rebuild a generator that continues exactly where :func:`generator_state` left it."""
    name = state["bit_generator"]
    bit_gen_cls = getattr(np.random, str(name), None)
    if bit_gen_cls is None or not isinstance(bit_gen_cls, type):
        raise ValueError(f"unknown bit generator {name!r} in state dict")
    bit_gen = bit_gen_cls()
    bit_gen.state = _from_jsonable(dict(state))
    return np.random.Generator(bit_gen)


def pack_meta(meta: Mapping[str, Any]) -> npt.NDArray[np.str_]:
    """Metadata as a 0-d unicode array (JSON)."""
    return np.array(json.dumps(dict(meta), sort_keys=True))


def model_meta(kind: str, d_x: int, d_y: int, params: Mapping[str, Any],
               rngs: tuple[np.random.Generator, np.random.Generator],
               **counters: int) -> npt.NDArray[np.str_]:
    """A model's ``"meta"`` entry (:func:`pack_meta`): the schema, ``kind``, the dimensions,
    the parameters (``RogerParams.to_mapping``), the learning and prediction generators'
    states, and the model's ``counters``."""
    return pack_meta({"schema": SCHEMA_VERSION, "kind": kind, "d_x": d_x, "d_y": d_y,
                      "params": dict(params), "rng_learn": generator_state(rngs[0]),
                      "rng_predict": generator_state(rngs[1]), **counters})


def unpack_meta(state: Mapping[str, np.ndarray], kind: str | None = None) -> dict[str, Any]:
    """Parse and check ``state["meta"]``; ``kind`` checks the model kind."""
    if "meta" not in state:
        raise ValueError("state dict has no 'meta' entry")
    meta = json.loads(str(np.asarray(state["meta"])[()]))
    if not isinstance(meta, dict):
        raise ValueError("state dict 'meta' is not a JSON object")
    version = meta.get("schema")
    if version not in READABLE_SCHEMAS:
        raise ValueError(f"state dict schema {version!r} is not supported "
                         f"(this version reads schemas {READABLE_SCHEMAS})")
    if kind is not None and meta.get("kind") != kind:
        raise ValueError(f"state dict holds a {meta.get('kind')!r} model, not {kind!r}")
    return meta


def pack_experts(gps: list[SparseOnlineGP], d_x: int, d_y: int) -> dict[str, np.ndarray]:
    """Concatenate the experts' live arrays (C and Q flattened) into flat named arrays."""
    ns = np.array([g.n for g in gps], dtype=np.int64)
    return {
        "expert_n_bv": ns,
        "expert_n_points": np.array([g.n_points for g in gps], dtype=np.int64),
        "expert_alloc": np.array([g.alloc for g in gps], dtype=np.int64),
        "expert_B": np.concatenate([g.B for g in gps]) if gps else np.zeros((0, d_x)),
        "expert_A": (np.concatenate([g._A[: g.n] for g in gps]) if gps
                     else np.zeros((0, d_y))),
        "expert_mean": (np.stack([g.mean_offset for g in gps]) if gps
                        else np.zeros((0, d_y))),
        "expert_C": np.concatenate([g.C.ravel() for g in gps]) if gps else np.zeros(0),
        "expert_Q": np.concatenate([g.Q.ravel() for g in gps]) if gps else np.zeros(0),
        # the hot path's cached diag(C) + diag(Q) (NaN where none): restores bit-exactly
        "expert_diag_cache": (np.concatenate([np.full(g.n, np.nan) if g._dg is None else g._dg
                                              for g in gps]) if gps else np.zeros(0)),
    }


def unpack_experts(state: Mapping[str, np.ndarray],
                   factory: Callable[[], SparseOnlineGP]) -> list[SparseOnlineGP]:
    """Inverse of :func:`pack_experts`; ``factory()`` makes an empty expert."""
    ns = np.asarray(state["expert_n_bv"], dtype=np.int64)
    counts = np.asarray(state["expert_n_points"], dtype=np.int64)
    allocs = np.asarray(state["expert_alloc"], dtype=np.int64)
    b_all, a_all = state["expert_B"], state["expert_A"]
    c_all, q_all = state["expert_C"], state["expert_Q"]
    dg_all = state["expert_diag_cache"]
    means = state.get("expert_mean")  # absent in schema 1: zero prior means
    out: list[SparseOnlineGP] = []
    row = 0
    flat = 0
    for n, cnt, alloc in zip(ns.tolist(), counts.tolist(), allocs.tolist(), strict=True):
        gp: SparseOnlineGP = factory()
        dg = dg_all[row:row + n]
        gp.load(b_all[row:row + n], a_all[row:row + n],
                c_all[flat:flat + n * n].reshape(n, n), q_all[flat:flat + n * n].reshape(n, n),
                cnt, alloc=alloc, diag_cache=None if np.isnan(dg).any() else dg,
                mean=None if means is None else means[len(out)])
        row += n
        flat += n * n
        out.append(gp)
    return out

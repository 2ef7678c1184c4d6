"""Helpers for ``state_dict``: flat named arrays plus JSON metadata, never pickle.

A state dict is ``dict[str, np.ndarray]`` with numeric arrays only, plus ``"meta"``: a 0-d
unicode array holding a JSON object (schema version, model kind, dimensions, parameters,
random-generator states, counters).  ``np.savez`` and ``np.load(allow_pickle=False)`` round-trip
it unchanged.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = [
    "SCHEMA_VERSION",
    "generator_from_state",
    "generator_state",
    "pack_meta",
    "spawn_generators",
    "unpack_meta",
]

SCHEMA_VERSION = 1

Seed = int | np.random.Generator | None


def spawn_generators(seed: Seed) -> tuple[np.random.Generator, np.random.Generator]:
    """Two independent streams from one seed: (learning, prediction).

    Predictions draw only from the second stream, so they never perturb learning.
    """
    if isinstance(seed, np.random.Generator):
        learn, predict = seed.spawn(2)
        return learn, predict
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer)):
        raise TypeError(f"seed must be an int, a numpy Generator or None, got {seed!r}")
    children = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(children[0]), np.random.default_rng(children[1])


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


def unpack_meta(state: Mapping[str, np.ndarray], kind: str | None = None) -> dict[str, Any]:
    """Parse and check ``state["meta"]``; ``kind`` checks the model kind."""
    if "meta" not in state:
        raise ValueError("state dict has no 'meta' entry")
    meta = json.loads(str(np.asarray(state["meta"])[()]))
    if not isinstance(meta, dict):
        raise ValueError("state dict 'meta' is not a JSON object")
    version = meta.get("schema")
    if version != SCHEMA_VERSION:
        raise ValueError(f"state dict schema {version!r} is not supported "
                         f"(this version reads schema {SCHEMA_VERSION})")
    if kind is not None and meta.get("kind") != kind:
        raise ValueError(f"state dict holds a {meta.get('kind')!r} model, not {kind!r}")
    return meta

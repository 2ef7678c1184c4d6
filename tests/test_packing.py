"""protocols.packing: msgpack's bytes, with buffers the size of the message."""

from __future__ import annotations

import tracemalloc
from typing import Any

import msgpack
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from protocols.packing import packb, walker

# the mmap threshold the daemon and its workers fix (roger_daemon.daemon.memory)
MAPPED = 128 * 1024

_scalars = (st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1)
            | st.floats(allow_nan=False) | st.text(max_size=40) | st.binary(max_size=300))
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=6)
                       | st.dictionaries(st.text(max_size=10), inner, max_size=6), max_leaves=30)


@given(_values)
def test_packb_gives_msgpacks_bytes(value: Any) -> None:
    assert packb(value) == msgpack.packb(value, use_bin_type=True)


def _peak_bytes(fn: Any) -> int:
    tracemalloc.start()
    try:
        fn()
        return int(tracemalloc.get_traced_memory()[1])
    finally:
        tracemalloc.stop()


def test_a_message_is_packed_and_walked_without_a_mapped_buffer() -> None:
    msg = {"op": "learn", "x": np.arange(6.0).tobytes(), "y": np.ones(2).tobytes(),
           "code": 3, "tick": 12345}
    payload = packb(msg)
    assert _peak_bytes(lambda: packb(msg)) < MAPPED
    assert _peak_bytes(lambda: walker(payload)) < MAPPED


def test_a_large_value_grows_the_buffer() -> None:
    state = {"C": np.random.default_rng(0).standard_normal(300 * 300).tobytes(), "n": 300}
    payload = packb(state)
    assert payload == msgpack.packb(state, use_bin_type=True)
    assert msgpack.unpackb(payload, raw=False) == state


def test_walker_reads_the_message_value_by_value() -> None:
    payload = packb({"robot": "r0", "tick": 7, "mode": "learn+predict"})
    walk = walker(payload)
    n = walk.read_map_header()
    assert [(walk.unpack(), walk.unpack()) for _ in range(n)] == [
        ("robot", "r0"), ("tick", 7), ("mode", "learn+predict")]
    assert walk.tell() == len(payload)

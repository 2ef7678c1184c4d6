"""msgpack with buffers sized for messages: the one place the wire and the daemon pack.

``msgpack.packb`` builds a ``Packer`` whose buffer starts at 256 KiB, and ``msgpack.Unpacker()``
one whose buffer starts at 1 MiB. The daemon and its learner workers serve every allocation of
128 KiB or more from a mapping of its own (``roger_daemon.daemon.memory``, which keeps their
memory flat), so each of those calls mapped, touched and unmapped its buffer: ~10 µs for a
learn request on an idle machine instead of ~0.7 µs, more on a busy one, and an unmapping in
a process with several threads interrupts the other cores. With eight robots the loop made
~56 such calls per tick and its workers ~24 (docs/performance.md, *msgpack's buffers*).
Here the buffer starts small and grows with the message; the bytes are the same as
``msgpack.packb``'s.
"""

from __future__ import annotations

from typing import Any

import msgpack

__all__ = ["packb", "walker"]

#: the first size of a packer's buffer: a learn request, a prediction with its multimap or a
#: status fits; a larger message (a model state) grows it
PACK_BUFFER = 4096


def packb(obj: Any) -> bytes:
    """``msgpack.packb(obj, use_bin_type=True)``, the same bytes, without the 256-KiB buffer.

    A new packer per call: packers are not thread-safe, and one is cheap when its buffer is
    small."""
    out: bytes = msgpack.Packer(use_bin_type=True, buf_size=PACK_BUFFER).pack(obj)
    return out


def walker(payload: bytes) -> msgpack.Unpacker:
    """An ``Unpacker`` (``raw=False``) fed ``payload``, to walk one message value by value,
    its buffer the payload's size instead of 1 MiB."""
    walk = msgpack.Unpacker(raw=False, read_size=max(len(payload), 64))
    walk.feed(payload)
    return walk

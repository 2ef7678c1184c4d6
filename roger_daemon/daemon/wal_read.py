"""Reading the write-ahead log back: every record a CRC proves intact, and where it is damaged.

The frame layout is that of :mod:`roger_daemon.daemon.wal` (``u32 length | u32 crc32(payload)
| payload``, zeros after the last record). A frame that is short, fails its CRC or does not
decode is *damage*: the reader reports it with its segment and byte offset and looks for the
next frame that proves itself (a plausible length, a matching CRC32, a payload that decodes to
a record with a higher sequence number), so one flipped byte costs one record, not the rest of
the segment (docs/durability.md, *Torn and corrupt records*). Damage with no intact frame
after it is a torn tail (a write the kill interrupted: never acknowledged, since its commit
had not returned, unless the disk itself lost it).

The sequence numbers of the records on both sides of a damaged stretch name what it held:
:attr:`WalDamage.lost_seqs`.
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

__all__ = ["FRAME", "MAX_RECORD", "WalDamage", "WalLog", "WalRecord", "read_log",
           "read_records", "scan_segment", "segments"]

FRAME = struct.Struct("<II")
MAX_RECORD = 1 << 20
_NAME = re.compile(r"^wal-(\d{12})\.log$")
#: the first byte of a record's payload: a msgpack map (fixmap, map16, map32)
_MAP_FIRST = frozenset(range(0x80, 0x90)) | {0xDE, 0xDF}


@dataclass(frozen=True)
class WalRecord:
    """One decision read back: a learned pair (``kind == "pair"``) or a fresh model."""

    kind: str
    seq: int
    index: int = -1
    tick: int = -1
    x: np.ndarray | None = None
    y: np.ndarray | None = None
    label: str = ""


@dataclass(frozen=True)
class WalDamage:
    """A stretch of a segment no intact frame covers: ``offset`` and ``length`` in bytes.

    ``after_seq``/``before_seq``: the sequence numbers of the intact records around it (-1:
    none before it in the segment; None: none after it, a torn tail)."""

    path: Path
    offset: int
    length: int
    after_seq: int
    before_seq: int | None

    @property
    def torn_tail(self) -> bool:
        """Nothing intact follows it in its segment."""
        return self.before_seq is None

    @property
    def lost_seqs(self) -> range:
        """The sequence numbers the stretch held, as far as its neighbours prove."""
        if self.before_seq is None:
            return range(self.after_seq + 1, self.after_seq + 1)
        return range(self.after_seq + 1, self.before_seq)

    def describe(self) -> str:
        """One line naming the file, the offset and what was lost."""
        what = ("torn or corrupt tail" if self.torn_tail else
                f"corrupt record(s), seq {self.lost_seqs.start}..{self.lost_seqs.stop - 1}"
                if len(self.lost_seqs) else "corrupt bytes")
        return f"{self.path.name} offset {self.offset}: {what} ({self.length} bytes skipped)"


@dataclass
class WalLog:
    """Every intact record of a log (in sequence order) and every damaged stretch."""

    records: list[WalRecord] = field(default_factory=list)
    damage: list[WalDamage] = field(default_factory=list)


def segments(directory: Path) -> list[tuple[int, Path]]:
    """``(first seq, path)`` of every segment, oldest first."""
    if not directory.is_dir():
        return []
    out = []
    for p in directory.iterdir():
        m = _NAME.match(p.name)
        if m and p.is_file():
            out.append((int(m.group(1)), p))
    return sorted(out)


def _decode(payload: bytes) -> WalRecord | None:
    try:
        m: Any = msgpack.unpackb(payload, raw=False)
    except Exception:
        return None
    if not isinstance(m, dict) or not isinstance(m.get("s"), int):
        return None
    if m.get("k") == "fresh":
        return WalRecord("fresh", m["s"])
    if m.get("k") != "pair":
        return None
    try:
        x = np.frombuffer(m["x"], dtype="<f8").copy()
        y = np.frombuffer(m["y"], dtype="<f8").copy()
        return WalRecord("pair", m["s"], int(m["i"]), int(m["tick"]), x, y, str(m["label"]))
    except (KeyError, TypeError, ValueError):
        return None


def _frame_at(data: bytes, pos: int, after_seq: int) -> tuple[WalRecord, int] | None:
    """The record of an intact frame at ``pos`` and where the next frame starts, or None."""
    if pos + FRAME.size > len(data):
        return None
    length, crc = FRAME.unpack_from(data, pos)
    end = pos + FRAME.size + length
    if length == 0 or length > MAX_RECORD or end > len(data):
        return None
    if data[pos + FRAME.size] not in _MAP_FIRST:
        return None
    payload = data[pos + FRAME.size: end]
    if zlib.crc32(payload) != crc:
        return None
    rec = _decode(payload)
    if rec is None or rec.seq <= after_seq:
        return None
    return rec, end


def scan_segment(path: Path) -> WalLog:
    """The intact records of one segment and its damaged stretches (see the module)."""
    data = path.read_bytes()
    used = len(data.rstrip(b"\0"))  # zeros after the last record: the preallocated rest
    out = WalLog()
    pos, last = 0, -1
    while pos < used:
        got = _frame_at(data, pos, last)
        if got is not None:
            rec, pos = got
            out.records.append(rec)
            last = rec.seq
            continue
        nxt = _resync(data, pos + 1, used, last)
        if nxt is None:
            out.damage.append(WalDamage(path, pos, used - pos, last, None))
            return out
        out.damage.append(WalDamage(path, pos, nxt[0] - pos, last, nxt[1].seq))
        pos = nxt[0]
    return out


def _resync(data: bytes, start: int, used: int, after_seq: int
            ) -> tuple[int, WalRecord] | None:
    """The first offset from ``start`` where an intact frame begins, with its record."""
    for p in range(start, used):
        got = _frame_at(data, p, after_seq)
        if got is not None:
            return p, got[0]
    return None


def read_log(directory: Path) -> WalLog:
    """Every intact record of every segment, in order, and every damaged stretch."""
    out = WalLog()
    for _, path in segments(directory):
        seg = scan_segment(path)
        last = out.records[-1].seq if out.records else -1
        out.records.extend(r for r in seg.records if r.seq > last)
        out.damage.extend(seg.damage)
    return out


def read_records(directory: Path, after_seq: int = -1) -> list[WalRecord]:
    """Every intact record with ``seq > after_seq``, in order (damage skipped)."""
    return [r for r in read_log(directory).records if r.seq > after_seq]

"""MCAP inspection helpers shared by the log-tool and regression-session tests."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader, breakup_chunk

__all__ = ["chunk_ends", "messages"]


def chunk_ends(path: Path) -> list[tuple[int, int]]:
    """(end offset, messages) of every chunk, from mcap's own chunk index."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        out = []
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset)
            rec = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            assert isinstance(rec, Chunk)
            n = sum(type(r).__name__ == "Message" for r in breakup_chunk(rec))
            out.append((ci.chunk_start_offset + ci.chunk_length, n))
    return out


def messages(path: Path) -> list[tuple[str, int, int, int, bytes]]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time, m.sequence, m.data)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]

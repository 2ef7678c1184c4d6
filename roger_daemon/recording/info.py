"""``roger log info``: what a log holds (channels, counts, duration, rates, gaps, metadata).

The report depends only on the file's bytes (no clock, no terminal width), so the text and the
JSON of a fixed file are stable.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.recording.mcapio import LogReader

__all__ = ["format_info", "log_info"]


def _utc(ns: int | None) -> str:
    if ns is None:
        return ""
    s, frac = divmod(int(ns), 1_000_000_000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(s)) + f".{frac // 1_000_000:03d}Z"


def log_info(path: str | Path) -> dict[str, Any]:
    """Summarise one MCAP file (read linearly, so a footer-less file works too)."""
    reader = LogReader(Path(path))
    times: dict[int, list[int]] = {}
    seqs: dict[int, list[int]] = {}
    attachments: list[dict[str, Any]] = []
    for rec in reader.records():
        name = type(rec).__name__
        if name == "Message":
            times.setdefault(rec.channel_id, []).append(rec.log_time)  # type: ignore[attr-defined]
            seqs.setdefault(rec.channel_id, []).append(rec.sequence)  # type: ignore[attr-defined]
        elif name == "Attachment":
            attachments.append(
                {"name": rec.name, "media_type": rec.media_type,  # type: ignore[attr-defined]
                 "bytes": len(rec.data)}  # type: ignore[attr-defined]
            )
    channels = []
    all_first: list[int] = []
    all_last: list[int] = []
    for cid, ch in sorted(reader.channels.items()):
        t = np.sort(np.asarray(times.get(cid, []), dtype=np.int64))
        n = int(t.size)
        entry: dict[str, Any] = {
            "id": cid,
            "topic": ch.topic,
            "message_encoding": ch.message_encoding,
            "schema": reader.schemas[ch.schema_id].name if ch.schema_id in reader.schemas else "",
            "messages": n,
            "first_ns": int(t[0]) if n else None,
            "last_ns": int(t[-1]) if n else None,
            "duration_s": round(float(t[-1] - t[0]) / 1e9, 6) if n else 0.0,
            "rate_hz": 0.0,
            "max_gap_s": 0.0,
            "max_gap_after_ns": None,
            "sequence_first": None,
            "sequence_last": None,
        }
        if n:
            all_first.append(int(t[0]))
            all_last.append(int(t[-1]))
            sq = seqs[cid]
            entry["sequence_first"], entry["sequence_last"] = int(sq[0]), int(sq[-1])
        if n >= 2:
            span = float(t[-1] - t[0])
            gaps = np.diff(t)
            g = int(np.argmax(gaps))
            entry["rate_hz"] = round((n - 1) / (span / 1e9), 3) if span > 0 else 0.0
            entry["max_gap_s"] = round(float(gaps[g]) / 1e9, 6)
            entry["max_gap_after_ns"] = int(t[g])
        channels.append(entry)
    start = min(all_first) if all_first else None
    end = max(all_last) if all_last else None
    header = reader.header
    return {
        "file": str(path),
        "bytes": reader.bytes_total,
        "complete": reader.complete,
        "readable_bytes": reader.bytes_valid,
        "stopped_because": reader.error,
        "library": header.library if header else "",
        "profile": header.profile if header else "",
        "chunks": reader.chunks,
        "messages": sum(c["messages"] for c in channels),
        "start_ns": start,
        "end_ns": end,
        "start_utc": _utc(start),
        "end_utc": _utc(end),
        "duration_s": round((end - start) / 1e9, 6) if start is not None and end is not None
        else 0.0,
        "channels": channels,
        "schemas": sorted({s.name for s in reader.schemas.values()}),
        "metadata": {m.name: dict(sorted(m.metadata.items())) for m in reader.metadata},
        "attachments": attachments,
    }


def _short(v: str, width: int = 72) -> str:
    lines = v.splitlines()
    first = lines[0] if lines else ""
    more = f" ... ({len(lines)} lines)" if len(lines) > 1 else ""
    if len(first) > width:
        first = first[: width - 3] + "..."
    return first + more


def format_info(info: dict[str, Any]) -> str:
    """The human-readable form of :func:`log_info` (plain text, stable)."""
    out = [
        f"file:      {info['file']}",
        f"bytes:     {info['bytes']}"
        + ("" if info["complete"] else f" (readable {info['readable_bytes']})"),
        "complete:  "
        + ("yes (footer, summary, indexes)" if info["complete"]
           else f"NO: {info['stopped_because']} -- run `roger log recover`"),
        f"library:   {info['library']}",
        f"start:     {info['start_utc']}",
        f"end:       {info['end_utc']}",
        f"duration:  {info['duration_s']:.3f} s",
        f"messages:  {info['messages']} in {info['chunks']} chunks",
        "channels:",
    ]
    rows = [("topic", "schema", "enc", "msgs", "rate Hz", "max gap s", "seq")]
    for c in info["channels"]:
        seq = "" if c["sequence_first"] is None else f"{c['sequence_first']}..{c['sequence_last']}"
        rows.append(
            (
                c["topic"],
                c["schema"] or "-",
                c["message_encoding"],
                str(c["messages"]),
                f"{c['rate_hz']:.2f}",
                f"{c['max_gap_s']:.3f}",
                seq,
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        cells = [
            r[i].ljust(widths[i]) if i < 3 else r[i].rjust(widths[i]) for i in range(len(r))
        ]
        out.append("  " + "  ".join(cells).rstrip())
    for name, meta in info["metadata"].items():
        out.append(f"metadata {name}:")
        for k, v in meta.items():
            out.append(f"  {k}: {_short(v)}")
    for a in info["attachments"]:
        out.append(f"attachment: {a['name']} ({a['media_type']}, {a['bytes']} bytes)")
    return "\n".join(out)

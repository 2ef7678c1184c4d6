"""Re-learning the write-ahead log after a checkpoint, across damage (docs/durability.md).

:func:`replay_into` re-learns every intact record after the checkpoint's ``wal_seq``. A pair
the log lost (a damaged record, or segments pruned after a checkpoint that turned out
unreadable) shows as a gap in the pairs' indices; it is taken from another copy when one
survives (``copies``: the session logs' decision records, see ``roger_daemon.daemon.copies``),
else counted as lost and the records after it are learned all the same: every intact record
is kept.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_daemon.daemon.wal_read import WalDamage, WalRecord, read_log

__all__ = ["Copies", "Replayed", "replay_into"]

#: ``copies(indices, anchor)``: pairs of the model's history with those indices, in order (as
#: many consecutive ones from the first as survive); ``anchor`` is the log's record just
#: after them (None at the end of the log), which a copy must agree with
Copies = Callable[[range, WalRecord | None], Sequence[WalRecord]]
#: the tail asked of ``copies`` after the log's last record: "as many as there are"
_TAIL = 1 << 40


@dataclass
class Replayed:
    """What :func:`replay_into` did."""

    pairs: int = 0  # re-learned from the log
    fresh: int = 0
    copied: int = 0  # pairs the log had lost, re-learned from another copy
    lost: int = 0  # pairs the log had lost and no copy held (skipped)
    first_tick: int | None = None
    last_tick: int | None = None
    stopped: str = ""  # why replay stopped before the end ("" if it did not)
    next_seq: int = 0  # sequence number for the next record
    damage: list[WalDamage] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _learn(rt: Any, r: WalRecord, out: Replayed) -> None:
    assert r.x is not None and r.y is not None
    rt.relearn(r.x, r.y, r.label, r.tick)
    out.first_tick = r.tick if out.first_tick is None else out.first_tick
    out.last_tick = r.tick


def _fill(rt: Any, wanted: range, anchor: WalRecord | None, copies: Copies | None,
          out: Replayed) -> None:
    """Learn what ``copies`` holds of ``wanted`` (the pairs the log lost), in order."""
    if copies is None or out.fresh or out.lost:  # another history than the copies' own
        return
    for p in copies(wanted, anchor):
        if p.index != rt.updates:
            break
        _learn(rt, p, out)
        out.copied += 1


def replay_into(rt: Any, directory: Path, after_seq: int, *,
                copies: Copies | None = None) -> Replayed:
    """Re-learn into ``rt`` (a RobotRuntime, WAL not attached) every intact decision after
    ``after_seq``: ``fresh`` records reset the model, pair records are learned in order.

    A pair whose index is past the model's ``n_learned`` (pairs lost: damage, or segments
    pruned after a lost checkpoint) is preceded by the missing pairs from ``copies`` if they
    survive there, else they are counted in :attr:`Replayed.lost` and skipped. A pair of index
    0 after damage means a lost reset record (the model is reset). A pair behind the model
    stops the replay; the rest is reported, not guessed.
    """
    log_ = read_log(directory)
    out = Replayed(damage=log_.damage)
    out.next_seq = log_.records[-1].seq + 1 if log_.records else 0
    shift = 0  # pairs of the log's numbering that the model lacks (lost, not copied)
    for r in log_.records:
        if r.seq <= after_seq:
            continue
        if r.kind == "fresh":
            rt.reset()
            out.fresh += 1
            shift = 0
            continue
        if r.index == 0 and rt.updates > 0 and log_.damage:
            out.notes.append(f"record {r.seq} is pair 0 after damage: a lost reset, applied")
            rt.reset()
            out.fresh += 1
            shift = 0
        if r.index - shift > rt.updates:
            _fill(rt, range(rt.updates + shift, r.index), r, copies, out)
            missing = r.index - shift - rt.updates
            if missing > 0:
                out.notes.append(f"pairs {r.index - missing}..{r.index - 1} (before record "
                                 f"{r.seq}, tick {r.tick}) are lost: no intact copy")
                out.lost += missing
                shift += missing
        if r.index - shift < rt.updates:
            out.stopped = (f"record {r.seq} is pair {r.index} but the model has {rt.updates} "
                           "pairs (a gap in the log); the rest is not used")
            break
        _learn(rt, r, out)
        out.pairs += 1
    if log_.damage and not out.stopped:  # a damaged tail: what the copies hold after it
        _fill(rt, range(rt.updates, _TAIL), None, copies, out)
    return out

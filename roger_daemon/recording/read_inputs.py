"""The reader of version-1 session logs: the learned pairs re-derived from the recorded inputs.

Logs of older daemons and of ``roger record`` hold what was received and published but not the
daemon's decisions, so the learned pairs are re-derived, in the log's write order (the order
the daemon handled messages in), with the daemon's own rules:

* **Pairing** with the daemon's :class:`~roger_daemon.daemon.pairing.Pairing` (the session's
  ``pair_window``, default 64), only while the mode learns (``learn``, ``learn+predict``); in
  the other modes perceptions and actions are not buffered at all (counted in
  :attr:`Timeline.ignored_not_learning`). Payloads that fail ``protocols.decode`` are skipped.
* **Learning order** = pair formation order (the daemon's FIFO training queue). A pair the
  daemon did not queue (its queue was full, or a re-sent copy) is named by a record on
  ``roger/<robot>/daemon/dropped`` right after the message that completed it, and is removed
  (:attr:`Timeline.dropped_recorded`). Logs from daemons that did not write these records only
  show the ``dropped`` counter of the status messages; replay warns when that says more.
* **Mode** starts as the metadata's ``mode`` and follows ``control`` messages ``op=mode``.
* **Reset** (``control`` ``op=reset``) starts a new segment with a fresh model and empties the
  pairing buffers.

Version-2 logs name every learned pair instead (:mod:`roger_daemon.recording.timeline`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import msgpack

from protocols.messages import Action, Control, Perception
from roger_daemon.daemon.pairing import LEARN_MODES, Pairing
from roger_daemon.recording.mcapio import LogMessage
from roger_daemon.recording.session_read import Reading
from roger_daemon.recording.timeline import LearnedPair, Segment, Timeline

__all__ = ["InputsReading", "dropped_tick"]


class InputsReading(Reading):
    """Version 1: pair the recorded inputs as the daemon did (see the module doc)."""

    def __init__(self, tl: Timeline, mode: str | None, predictions: bool) -> None:
        super().__init__(tl, predictions)
        self.mode = mode
        self.pairing = Pairing(tl.pair_window)

    def perception(self, msg: Perception, t_ns: int) -> None:
        """Pair it while the mode learns."""
        if self.mode not in LEARN_MODES:
            self.tl.ignored_not_learning += 1
            return
        pair = self.pairing.perception(msg)
        if pair is not None:
            self._learned(*pair, t_ns)

    def action(self, msg: Action, t_ns: int) -> None:
        """Pair it while the mode learns."""
        if self.mode not in LEARN_MODES:
            self.tl.ignored_not_learning += 1
            return
        pair = self.pairing.action(msg)
        if pair is not None:
            self._learned(*pair, t_ns)

    def _learned(self, p: Perception, a: Action, t_ns: int) -> None:
        seg = self.segment
        seg.pairs.append(LearnedPair(index=seg.end_updates, tick=p.tick, x=p.x, y=a.y,
                                     label=a.label, log_time_ns=t_ns))

    def control(self, msg: Control) -> None:
        """Mode changes and resets."""
        if msg.op == "mode":
            self.mode = msg.mode
        elif msg.op == "reset":
            self.tl.segments.append(Segment(start_updates=0, after_reset=True))
            self.pairing = Pairing(self.tl.pair_window)

    def decision(self, event: str, lm: LogMessage) -> None:
        """A drop record removes the pair it names (other records: a version-2 log read by
        these rules, ignored)."""
        if event == "dropped":
            _drop(self.tl, self.segment, lm.message.data)

    def finish(self) -> None:
        """Dims, and what was left unpaired."""
        super().finish()
        self.tl.unpaired = self.pairing.pending


def dropped_tick(payload: bytes) -> int:
    """The tick of a drop record (any version of it); ``ValueError`` if it is not one."""
    try:
        m: Any = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception as exc:
        raise ValueError(f"drop record is not msgpack ({exc})") from None
    tick = m.get("tick") if isinstance(m, dict) else None
    if isinstance(tick, bool) or not isinstance(tick, int) or tick < 0:
        raise ValueError(f"drop record without a valid tick: {m!r:.80}")
    return tick


def _drop(tl: Timeline, seg: Segment, payload: bytes) -> None:
    """Apply a drop record: the newest formed pair of its tick was never learned."""
    try:
        tick = dropped_tick(payload)
    except ValueError:
        tl.invalid["bad_drop_record"] += 1
        return
    for i in range(len(seg.pairs) - 1, -1, -1):
        if seg.pairs[i].tick == tick:
            del seg.pairs[i]
            for j in range(i, len(seg.pairs)):  # renumber (normally nothing follows)
                seg.pairs[j] = replace(seg.pairs[j], index=seg.first_index + j)
            tl.dropped_recorded += 1
            return
    tl.dropped_unmatched += 1

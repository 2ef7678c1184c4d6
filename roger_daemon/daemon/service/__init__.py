"""The daemon's service loop (:class:`Service`) and its parts, one concept a module.

:mod:`.loop` is the loop itself; :mod:`.intake`, :mod:`.answers`, :mod:`.schedule`,
:mod:`.status`, :mod:`.outbox`, :mod:`.checkpoints`, :mod:`.recording` and :mod:`.shutdown`
are its parts (those written as functions take the :class:`Service` whose state they use).
"""

from __future__ import annotations

from roger_daemon.daemon.service.checkpoints import checkpoint_snapshot
from roger_daemon.daemon.service.clock import Clock
from roger_daemon.daemon.service.loop import Service
from roger_daemon.daemon.service.recording import Recorder

__all__ = ["Clock", "Recorder", "Service", "checkpoint_snapshot"]

"""How long another thread of the daemon's process may keep the GIL from the loop.

A thread that waits for the GIL asks its holder to drop it only after the interpreter's
switch interval (5 ms by default). In the daemon's process the loop shares the GIL with
Zenoh's callback threads, which take it once per message received, and with the write-ahead
log's committer threads. When a robot's messages arrive in a burst, the callback thread can
take the GIL back after each message before the waiting loop wakes, so the loop waits out the
whole interval: a realtime tick then publishes up to 5 ms late. With learner workers the loop
runs only short pieces of Python, so a shorter interval costs it little. Set for the realtime
clock only: lockstep has no tick to keep, and there the shorter interval was worse in two of
three alternated pairs (docs/fleet.md, *The switch interval*).
"""

from __future__ import annotations

import sys

__all__ = ["LOOP_SWITCH_INTERVAL_S", "shorten_switch_interval", "switch_interval_for"]

#: the daemon's switch interval in the realtime clock when learner workers own the models
LOOP_SWITCH_INTERVAL_S = 0.0005


def shorten_switch_interval(seconds: float = LOOP_SWITCH_INTERVAL_S) -> float:
    """Set this process's switch interval to ``seconds``; returns the one it replaces."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(seconds)
    return previous


def switch_interval_for(clock: str, workers: bool) -> float | None:
    """The loop's switch interval for a daemon on ``clock`` (with learner ``workers`` or
    inline); ``None``: the interpreter's own."""
    return LOOP_SWITCH_INTERVAL_S if workers and clock == "realtime" else None

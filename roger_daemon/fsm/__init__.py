"""Learned transitions over ROGER's experts: the robot plays alone (docs/autonomy.md).

Numerics only (numpy/scipy), no I/O; it reads a ROGER model's multimap and never the
demonstrator's labels::

    from roger_daemon.fsm import LearnedFSM, fit_fsm, aibo_memory
"""

from __future__ import annotations

from roger_daemon.fsm.controller import START, LearnedFSM, responsible_expert
from roger_daemon.fsm.fit import fit_fsm
from roger_daemon.fsm.memory import Memory, MemorySpec
from roger_daemon.fsm.profiles import aibo_memory
from roger_daemon.fsm.transitions import TransitionModel

__all__ = ["START", "LearnedFSM", "Memory", "MemorySpec", "TransitionModel", "aibo_memory",
           "fit_fsm", "responsible_expert"]

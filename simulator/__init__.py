"""The AIBO soccer simulator (pybullet), the hand-coded FSM, and the experiment orchestrator."""

from __future__ import annotations

__all__: list[str] = []

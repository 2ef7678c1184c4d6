"""``roger experiment goal-scoring``: the paper's experiment (section IV), end to end."""

from __future__ import annotations

__all__: list[str] = []

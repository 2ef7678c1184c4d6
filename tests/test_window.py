"""``Window`` percentiles: several from one sort are the floats of one call each."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.daemon.window import Window, percentiles

QS = (0.0, 1.0, 50.0, 90.0, 99.0, 100.0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False), max_size=60),
       st.integers(min_value=1, max_value=40))
def test_pcts_equal_one_percentile_call_each(values: list[float], size: int) -> None:
    w = Window(size)
    for v in values:
        w.add(v)
    kept = values[-size:]
    got = w.pcts(*QS)
    for q, g in zip(QS, got, strict=True):
        want = float(np.percentile(np.array(kept), q)) if kept else 0.0
        assert g == want  # exactly: the status reports the same numbers as before
        assert w.pct(q) == want


def test_empty_window_and_empty_sequence_give_zeros() -> None:
    assert Window(5).pcts(50, 99) == [0.0, 0.0]
    assert percentiles([], 50) == [0.0]
    assert percentiles([3.0, 1.0, 2.0], 0, 50, 100) == [1.0, 2.0, 3.0]

"""``as_vector``, the learner's check of every input and output vector (:mod:`.scaling`)."""

from __future__ import annotations

import numpy as np
import pytest

from roger_daemon.learner.scaling import as_vector


def test_a_finite_float64_vector_is_taken_as_it_is() -> None:
    x = np.array([0.5, -2.0, 3.0])
    assert as_vector("x", x, 3) is x


def test_finite_entries_whose_sum_overflows_are_accepted() -> None:
    big = np.array([1e308, 1e308, -1e308, 1e308])
    with np.errstate(over="ignore"):
        assert not np.isfinite(big.sum())
    assert as_vector("x", big, 4) is big


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_entry_is_refused_with_the_values(bad: float) -> None:
    for value in (np.array([1.0, bad]), [1.0, bad], np.array([np.inf, -np.inf])):
        with pytest.raises(ValueError, match="must be finite, got"):
            as_vector("y", value, 2)


def test_other_sequences_are_converted_and_shapes_checked() -> None:
    got = as_vector("x", [1, 2], 2)
    assert got.dtype == np.float64 and got.tolist() == [1.0, 2.0]
    assert as_vector("x", np.array([1, 2], dtype=np.int32), 2).dtype == np.float64
    assert as_vector("x", np.array([1.0, 2.0], dtype=np.float32), 2).dtype == np.float64
    with pytest.raises(ValueError, match=r"shape \(3,\), got shape \(2,\)"):
        as_vector("x", np.zeros(2), 3)
    with pytest.raises(ValueError, match=r"got shape \(1, 3\)"):
        as_vector("x", np.zeros((1, 3)), 3)
    with pytest.raises(ValueError, match="sequence of 2 finite floats"):
        as_vector("x", ["a", "b"], 2)

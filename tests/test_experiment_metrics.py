"""Experiment scores against hand-computed values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simulator.experiment.metrics import (
    downsample_per_label,
    majority_labels,
    segmentation_scores,
    success_rate,
)


def test_wilson_interval_matches_formula() -> None:
    r = success_rate([True] * 9 + [False] * 4)
    n, p, z = 13, 9 / 13, 1.959963984540054
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    assert r.rate == pytest.approx(p)
    assert r.ci_low == pytest.approx(centre - half, abs=1e-9)
    assert r.ci_high == pytest.approx(centre + half, abs=1e-9)


def test_downsample_keeps_order_and_limit() -> None:
    labels = ["seek"] * 50 + ["aim"] * 5 + ["seek"] * 50
    idx = downsample_per_label(labels, 20, np.random.default_rng(0))
    assert np.all(np.diff(idx) > 0)
    kept = [labels[i] for i in idx]
    assert kept.count("seek") == 20 and kept.count("aim") == 5
    again = downsample_per_label(labels, 20, np.random.default_rng(0))
    assert np.array_equal(idx, again)


def test_perfect_and_mixed_segmentation() -> None:
    labels = ["a"] * 4 + ["b"] * 4
    perfect = segmentation_scores([7, 7, 7, 7, 3, 3, 3, 3], labels)
    assert perfect.purity == 1.0 and perfect.ari == pytest.approx(1.0)
    assert perfect.nmi == pytest.approx(1.0)
    # expert 1 holds a,a,a,b ; expert 2 holds a,b,b,b -> purity 6/8
    mixed = segmentation_scores([1, 1, 1, 2, 1, 2, 2, 2], labels)
    assert mixed.purity == pytest.approx(0.75)
    assert mixed.ari < 0.5
    assert mixed.largest_share == {"a": 0.75, "b": 0.75}
    assert majority_labels([1, 1, 1, 2, 1, 2, 2, 2], labels) == {1: "a", 2: "b"}


def test_majority_tie_is_deterministic() -> None:
    assert majority_labels([0, 0], ["trap", "aim"]) == {0: "aim"}


def test_figures_are_written(tmp_path: Path) -> None:
    from simulator.experiment.figures import pca3, plot_experts_histogram, plot_pca, plot_success

    rng = np.random.default_rng(1)
    x = rng.normal(size=(60, 23))
    y = rng.normal(size=(60, 9))
    labels = ["seek", "trap", "aim", "kick"] * 15
    assign = [i % 5 for i in range(60)]
    p = pca3(np.hstack([x, y]))
    assert p.shape == (60, 3)
    # principal components are uncorrelated and sorted by variance
    var = p.var(axis=0)
    assert var[0] >= var[1] >= var[2]
    for f in (
        plot_pca(x, y, labels, assign, tmp_path / "pca.png"),
        plot_experts_histogram(assign, labels, tmp_path / "hist.png"),
        plot_success({"hcc": [1, 0.5], "roger": [0.5, 0]}, tmp_path / "succ.png"),
    ):
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

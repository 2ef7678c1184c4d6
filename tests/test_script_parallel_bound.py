"""``scripts/learner_parallel_bound.py`` (docs/performance.md, *An exact step on both cores*):
its compiled step does the passes it claims, on one thread and on two: every version's
``k^T C k`` as the learner's own kernel gives it, and a read-and-write pass over the ``C`` and
``Q`` of the updated versions only."""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numba
import numpy as np
import pytest
from script_testing import load_script

from roger_daemon.learner.synthetic import BENCH_D_X

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "learner_parallel_bound.py"


@functools.cache  # one module, so its kernel is compiled (or loaded from the cache) once
def _script() -> ModuleType:
    return load_script("learner_parallel_bound", SCRIPT)


@pytest.mark.parametrize("threads", [1, 2])
def test_step_reads_every_version_and_writes_the_updated_ones(threads: int) -> None:
    from roger_daemon.learner.engine import jit

    script = _script()
    beta, versions = 12, 5
    bases, cs, qs, coefs = script.versions_like_the_learner(versions, beta, 3,
                                                            np.random.default_rng(1))
    x = np.array([0.1, -0.2, 0.3])
    expected = sum(jit.expert_terms(bases[v], cs[v], coefs[v], x, 1.0, beta, beta)[2 * beta]
                   for v in range(versions))
    before_c, before_q = cs.copy(), qs.copy()
    updated = np.array([1, 3])
    default = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        total = script.exact_step_passes(bases, cs, qs, coefs, x, 1.0, beta, updated, 1e-3)
    finally:
        numba.set_num_threads(default)
    assert total == pytest.approx(expected, rel=1e-12)
    changed = [v for v in range(versions)
               if not (np.array_equal(cs[v], before_c[v]) and np.array_equal(qs[v], before_q[v]))]
    assert changed == [1, 3]


def test_floor_and_openblas_comparison_touch_what_they_claim() -> None:
    """The bytes-only floor reads every version's ``C`` and the updated ``Q`` (their sums) and
    leaves the matrices as they were; OpenBLAS's ``dspmv`` on the learner's packed buffer is
    the learner's ``C k``, up to rounding."""
    from roger_daemon.learner.engine import packed

    script = _script()
    beta, versions = 12, 5
    _, cs, qs, _ = script.versions_like_the_learner(versions, beta, 3, np.random.default_rng(2))
    before_c, before_q = cs.copy(), qs.copy()
    updated = np.array([0, 4])
    total = script.bytes_only_passes(cs, qs, updated)
    assert total == pytest.approx(float(cs.sum() + qs[updated].sum()), rel=1e-12)
    assert np.array_equal(cs, before_c) and np.array_equal(qs, before_q)
    ks = np.random.default_rng(3).uniform(0.0, 1.0, (versions, beta))
    ours = np.empty((versions, beta))
    script.learner_products(cs, ks, beta, ours)
    full = np.array([packed.unpack(cs[v], beta, beta) @ ks[v] for v in range(versions)])
    np.testing.assert_allclose(ours, full, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(script.openblas_products(cs, ks, beta), full, rtol=1e-12,
                               atol=1e-14)


def test_cli_reports_both_thread_counts() -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "--versions", "4", "--updated", "2",
                          "--beta", "40", "--steps", "20", "--json"],
                         capture_output=True, text=True, timeout=600, check=True)
    report = json.loads(out.stdout)
    assert report["one_thread_ms_per_step"] > 0 and report["2_threads_ms_per_step"] > 0
    assert report["storage"] == "float64" and report["updated_per_step"] == 2
    assert report["dim"] == BENCH_D_X  # the benchmark stream's perception, by default
    assert report["bytes_only_ms_per_step_2_threads"] > 0
    assert report["evaluations_ck_ms_learner_kernel"] > 0
    assert report["evaluations_ck_ms_openblas_dspmv"] > 0
    assert report["learner_vs_openblas_max_rel_diff"] < 1e-12
    bad = subprocess.run([sys.executable, str(SCRIPT), "--updated", "30"],
                         capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2
    assert "--updated must be between 0 and --versions (got 30)" in bad.stderr

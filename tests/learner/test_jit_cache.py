"""numba's on-disk cache tied to every kernel module (roger_daemon/learner/engine/jit_compile.py),
and the kernel value that skips libm where it underflows (jit_kernels.rbf)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from roger_daemon.learner.engine import jit_kernels
from roger_daemon.learner.engine.jit_compile import (
    FINGERPRINT_FILE,
    drop_stale_entries,
    source_fingerprint,
)

_ENTRIES = ("jit_kernels.expert_terms-225.py311.nbi", "jit_kernels.expert_terms-225.py311.1.nbc",
            "jit_batch.terms_batch-35.py311.2.nbc")
_OTHERS = ("other_module.f-3.py311.nbi", "notes.txt")


def _fill(folder: Path) -> None:
    for name in (*_ENTRIES, *_OTHERS):
        (folder / name).write_bytes(b"x")


def test_entries_built_from_other_sources_are_dropped_and_nothing_else(tmp_path: Path) -> None:
    _fill(tmp_path)
    assert drop_stale_entries(tmp_path, "a" * 64)  # no fingerprint yet: not trusted
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*_OTHERS, FINGERPRINT_FILE])
    assert (tmp_path / FINGERPRINT_FILE).read_text().strip() == "a" * 64
    _fill(tmp_path)  # entries built from these sources are kept
    assert not drop_stale_entries(tmp_path, "a" * 64)
    assert all((tmp_path / name).exists() for name in _ENTRIES)
    assert drop_stale_entries(tmp_path, "b" * 64)  # a kernel module changed
    assert not any((tmp_path / name).exists() for name in _ENTRIES)
    assert all((tmp_path / name).exists() for name in _OTHERS)


def test_an_unwritable_cache_directory_is_left_alone(tmp_path: Path) -> None:
    missing = tmp_path / "file"
    missing.write_bytes(b"")  # a file where the directory should be: nothing can be written
    assert not drop_stale_entries(missing / "cache", "a" * 64)


def test_the_fingerprint_covers_every_kernel_module(tmp_path: Path) -> None:
    for name in ("jit.py", "jit_a.py", "jit_b.py", "other.py"):
        (tmp_path / name).write_text(name)
    before = source_fingerprint(tmp_path)
    (tmp_path / "other.py").write_text("changed")
    assert source_fingerprint(tmp_path) == before  # not a kernel module
    for name in ("jit.py", "jit_b.py"):
        (tmp_path / name).write_text("changed " + name)
        assert source_fingerprint(tmp_path) != before
        before = source_fingerprint(tmp_path)


def test_importing_the_kernels_records_their_fingerprint_in_the_cache(tmp_path: Path) -> None:
    """A real process with its own cache directory: after the kernels load, the fingerprint
    of this checkout's kernel modules is there beside their entries."""
    code = ("import numpy as np\n"
            "from roger_daemon.learner.engine import jit_kernels as k\n"
            "k.kernel_vector(np.zeros((2, 1)), np.ones(1), 0.5, 2)\n"
            "print(k.kernel_vector._cache.cache_path)\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True, env=env)
    cache_dir = Path(out.stdout.strip())
    assert cache_dir.is_relative_to(tmp_path)
    assert (cache_dir / FINGERPRINT_FILE).read_text().strip() == source_fingerprint()
    assert any(cache_dir.glob("jit_kernels.kernel_vector-*.nbi"))


def test_the_kernel_value_is_the_float_of_math_exp_across_the_underflow() -> None:
    """Exact oracle: ``rbf(gamma, s)`` is ``math.exp(-gamma * s)`` bit for bit, on a grid
    dense around ``exp``'s underflow to zero (-745.13) and the skip's threshold (-750)."""
    args = np.concatenate([np.linspace(0.0, 740.0, 2001), np.linspace(740.0, 760.0, 20001),
                           np.linspace(760.0, 1e4, 2001), [np.inf]])
    for gamma in (1.0, 0.5, 49.99999999999999):
        for s in (args / gamma).tolist():
            got = jit_kernels.rbf(gamma, s)
            want = math.exp(-gamma * s)
            assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want), s
    assert jit_kernels.EXP_ZERO_BELOW <= -1075 * math.log(2.0) - 4.0  # 2**-1075: half a subnormal


def test_kernel_vectors_far_from_the_point_are_zero_as_numpy_makes_them() -> None:
    rng = np.random.default_rng(3)
    basis = rng.normal(size=(50, 23))
    x = basis[0] + 1e-3  # one near basis vector, the rest ~40 apart in squared distance
    gamma = 50.0
    want = np.exp(-gamma * ((basis - x) ** 2).sum(axis=1))
    got = jit_kernels.kernel_vector(basis, x, gamma, 50)
    assert np.count_nonzero(want) == np.count_nonzero(got) == 1
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=0.0)

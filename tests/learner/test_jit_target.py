"""The CPU the learner's kernels are compiled for (roger_daemon/learner/engine/jit_target.py): one
model on every x86-64 host that can run it, numba's default elsewhere or when the user chose."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from roger_daemon.learner.engine.jit_target import TARGET_CPU, TARGET_FEATURES, kernel_target

_ALL = dict.fromkeys(TARGET_FEATURES, True)

# compile one kernel in a fresh process and report the target numba compiled it for
_PROBE = """
import json, sys
import numpy as np
{before}
from roger_daemon.learner.engine import jit, jit_target
jit.kernel_vector(np.zeros((2, 3)), np.zeros(3), 1.0, 2)
from numba.core import registry
print(json.dumps({{"cpu": registry.cpu_target.target_context.codegen().magic_tuple()[1],
                  "features": registry.cpu_target.target_context.codegen().magic_tuple()[2],
                  "pinned": jit_target.pinned()}}))
"""


def test_an_x86_64_host_with_the_features_compiles_for_the_one_target() -> None:
    assert kernel_target("x86_64", {**_ALL, "avx512f": True}, {}) == TARGET_CPU
    assert kernel_target("AMD64", _ALL, {"PATH": "/bin"}) == TARGET_CPU


@pytest.mark.parametrize(("machine", "features", "env"), [
    ("aarch64", _ALL, {}),  # another architecture: the host's own code
    ("x86_64", {**_ALL, "avx2": False}, {}),  # a CPU that could not run the target's code
    ("x86_64", {k: v for k, v in _ALL.items() if k != "fma"}, {}),
    ("x86_64", _ALL, {"NUMBA_CPU_NAME": "generic"}),  # the user's choice stands
    ("x86_64", _ALL, {"NUMBA_CPU_FEATURES": "+avx2"}),
])
def test_numba_keeps_its_default_elsewhere(machine: str, features: dict[str, bool],
                                           env: dict[str, str]) -> None:
    assert kernel_target(machine, features, env) is None


def _probe(tmp_path: Path, before: str = "", **extra: str) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"), **extra)
    out = subprocess.run([sys.executable, "-c", _PROBE.format(before=before)], env=env,
                         capture_output=True, text=True, timeout=600, check=True)
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def _host_runs_the_target() -> bool:
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    import llvmlite.binding as llvm

    features = llvm.get_host_cpu_features()
    return all(features.get(name, False) for name in TARGET_FEATURES)


@pytest.mark.skipif(not _host_runs_the_target(), reason="the host cannot run the target's code")
def test_a_learner_process_compiles_for_the_target_not_the_host(tmp_path: Path) -> None:
    assert _probe(tmp_path) == {"cpu": TARGET_CPU, "features": "", "pinned": TARGET_CPU}


def test_the_users_numba_setting_and_an_earlier_kernel_are_respected(tmp_path: Path) -> None:
    chosen = _probe(tmp_path, NUMBA_CPU_NAME="generic")
    assert chosen["cpu"] == "generic" and chosen["pinned"] is None
    # a kernel compiled before the learner's: numba's target exists, one process never mixes two
    earlier = _probe(tmp_path, before="import numba\nnumba.njit(lambda v: v + 1)(1)")
    import llvmlite.binding as llvm

    assert earlier["cpu"] == llvm.get_host_cpu_name() and earlier["pinned"] is None

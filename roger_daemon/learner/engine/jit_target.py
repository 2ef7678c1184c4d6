"""The CPU the learner's kernels are compiled for: one model, not the host's.

numba compiles for the host's CPU by default, and LLVM then vectorises the kernels whose sums
may be reassociated (:mod:`.jit_kernels`) by that CPU model's cost model: on another CPU model
the same sums add up in another order.  From the same stream, code and OpenBLAS kernel, two
CPU models learned models whose last bits differed, then a few assignments, and the learned
controllers' episodes (docs/reproducibility.md, *The learner's kernels are compiled for one
CPU*).  So on every x86-64 host that can run it, the kernels are compiled for LLVM's
``haswell`` with its own features only (AVX2, FMA, BMI1/2, ...; no AVX-512): the same machine
code, so the same floats, on every such host.  Elsewhere (another architecture, an x86-64 CPU
without these features) numba's default stays, as it does when the user sets
``NUMBA_CPU_NAME`` or ``NUMBA_CPU_FEATURES``.

:func:`pin` must run before numba creates its CPU target (the first kernel decorated in the
process); :mod:`.jit_compile`, through which every kernel is compiled, calls it on import.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import Mapping

__all__ = ["TARGET_CPU", "TARGET_FEATURES", "compiled_for", "kernel_target", "pin", "pinned"]

#: LLVM's name of the CPU the kernels are compiled for
TARGET_CPU = "haswell"
#: the host features that CPU's code uses, each of which the host must have
TARGET_FEATURES = ("avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt", "movbe", "popcnt",
                   "sse4.2")
_X86_64 = ("x86_64", "amd64")


def kernel_target(machine: str, host_features: Mapping[str, bool],
                  env: Mapping[str, str]) -> str | None:
    """The CPU name to compile for (with no features beyond its own), or ``None`` for numba's
    default: on ``machine`` (``platform.machine()``) with ``host_features`` (llvmlite's map),
    unless ``env`` sets numba's own choice."""
    if "NUMBA_CPU_NAME" in env or "NUMBA_CPU_FEATURES" in env:
        return None
    if machine.lower() not in _X86_64:
        return None
    if not all(host_features.get(name, False) for name in TARGET_FEATURES):
        return None
    return TARGET_CPU


def pin() -> str | None:
    """Compile this process's kernels for :func:`kernel_target`'s CPU; returns it, or
    ``None`` where numba keeps its default (also when a kernel was compiled before, so that
    one process never mixes two targets)."""
    from numba.core import config, registry

    if "_toplevel_target_context" in vars(registry.cpu_target):  # numba's target exists
        return pinned()
    if platform.machine().lower() not in _X86_64:
        return None
    import llvmlite.binding as llvm

    target = kernel_target(platform.machine(), llvm.get_host_cpu_features(), os.environ)
    if target is not None:
        config.CPU_NAME = target  # type: ignore[attr-defined]
        config.CPU_FEATURES = ""  # type: ignore[attr-defined]
    return target


def pinned() -> str | None:
    """The CPU this process's kernels are compiled for when :func:`pin` chose it, else
    ``None`` (numba's default: the host, or what the user set; or numba not loaded)."""
    return TARGET_CPU if compiled_for() == TARGET_CPU else None


def compiled_for() -> str | None:
    """What this process's kernels are compiled for, for a run's record: LLVM's CPU name, with
    `` (host features)`` when numba adds the host's features to it (its default); ``None``
    where numba is not loaded (no kernel has run)."""
    if "numba" not in sys.modules:
        return None
    from numba.core import config

    name = config.CPU_NAME  # type: ignore[attr-defined]
    if name is None:
        import llvmlite.binding as llvm

        name = llvm.get_host_cpu_name()
    own = config.CPU_FEATURES == ""  # type: ignore[attr-defined]
    return str(name) if own else f"{name} (host features)"

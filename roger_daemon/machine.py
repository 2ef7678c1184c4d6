"""The machine record of a benchmark or experiment run: what ran it, how loaded, how fast.

Every ``roger bench`` command and ``roger experiment goal-scoring`` put this record in their
JSON (``"machine"``): the CPU model and count, Python, numpy, the platform, the BLAS and its
threads, the 1-minute load average at the start and at the end, how the machine's CPU time was
spent over the run (``cpu_time``: busy, idle, and *stolen* by the hypervisor, from
``/proc/stat``), a *speed probe*: two fixed reference workloads timed when the run starts, and
how far apart the first two CPUs are at the start and at the end (a cache line's round trip
between them, :mod:`.core_probe`). The probe is there because this project's machines are
shared virtual machines whose speed drifts (the same fleet run took 59 % of a core one evening
and 83 % the next, on an idle machine): two runs' figures are comparable only when their probes
are (docs/performance.md, *Comparing runs*). Stolen time is CPU time the virtual machine's
processes were ready to use and did not get; a few percent of it shows in the fleet's latency
tails (docs/fleet.md). The speed probe runs on one CPU and does not see the host's spells of
running the two vCPUs on cores far apart, which slow the learner's two threads; the round trip
does (docs/performance.md, *The slow spells are the two cores far apart*).
"""

from __future__ import annotations

import os
import platform
import sys
import time
from typing import Any

import numpy as np

from roger_daemon.blas import blas_info

__all__ = ["busy_cpu_s", "cpu_time_split", "cpu_times", "cross_core_ns", "describe", "finish",
           "machine_record", "speed_probe", "usable_cores"]

_PROBE_ELEMENTS = 1 << 23  # 64 MB of float64: larger than the caches of the machines we use
_PROBE_LOOP = 200_000
_CPU_TIMES_START = "_cpu_times_start"  # kept in the record between machine_record and finish
_KERNELS = "roger_daemon.learner.engine.jit_compile"  # loaded with the learner's first kernel


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _python_loop() -> int:
    total = 0
    for i in range(_PROBE_LOOP):
        total += i * i % 7
    return total


def speed_probe(repeats: int = 5) -> dict[str, float]:
    """Two reference workloads timed now, best of ``repeats`` (ms; smaller is faster).

    ``python_ms``: a fixed pure-Python loop (the interpreter: the learner's and the daemon's
    bookkeeping); ``memory_ms``: one pass summing 64 MB of float64 (memory bandwidth: the
    learner's passes over ``C`` and ``Q``). The best of several repeats is what the machine
    delivers when nothing preempts the probe.
    """
    data = np.ones(_PROBE_ELEMENTS)
    python = memory = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        _python_loop()
        t1 = time.perf_counter()
        float(data.sum())
        t2 = time.perf_counter()
        python = min(python, t1 - t0)
        memory = min(memory, t2 - t1)
    return {"python_ms": round(python * 1e3, 2), "memory_ms": round(memory * 1e3, 2)}


def cross_core_ns() -> float | None:
    """How far apart this process's first two CPUs are now: ns per round trip of a cache line
    between them (:func:`.core_probe.round_trip_ns`), ``None`` with fewer than two CPUs.
    Imports numba (the probe is compiled), so it is taken only with the speed probe."""
    from roger_daemon.core_probe import round_trip_ns

    return round_trip_ns()


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, which a container or ``taskset``
    narrows; not ``os.cpu_count()``)."""
    return len(os.sched_getaffinity(0))


def cpu_times(path: str = "/proc/stat") -> list[int] | None:
    """The machine's CPU time so far, in clock ticks summed over its CPUs: user, nice,
    system, idle, iowait, irq, softirq, steal (the first line of ``/proc/stat``, whose
    ``guest`` times are already counted in ``user`` and ``nice``); ``None`` where it cannot be
    read (not Linux)."""
    try:
        with open(path, encoding="ascii") as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    if len(fields) < 9 or fields[0] != "cpu":
        return None
    try:
        return [int(v) for v in fields[1:9]]
    except ValueError:
        return None


def cpu_time_split(start: list[int], end: list[int]) -> dict[str, float] | None:
    """How the machine's CPU time between two :func:`cpu_times` readings was spent, in %:
    busy (user, nice, system, irq, softirq), idle (idle, iowait) and stolen by the hypervisor
    (steal); ``None`` when no time passed.

    >>> cpu_time_split([0] * 8, [50, 0, 10, 30, 5, 0, 0, 5])
    {'busy_percent': 60.0, 'idle_percent': 35.0, 'steal_percent': 5.0}
    """
    d = [b - a for a, b in zip(start, end, strict=True)]
    total = sum(d)
    if total <= 0:
        return None
    _user, _nice, _system, idle, iowait, _irq, _softirq, steal = d
    return {"busy_percent": round(100 * _busy_ticks(d) / total, 2),
            "idle_percent": round(100 * (idle + iowait) / total, 2),
            "steal_percent": round(100 * steal / total, 2)}


def busy_cpu_s(start: list[int], end: list[int]) -> float:
    """CPU seconds the machine's CPUs spent busy between two :func:`cpu_times` readings,
    summed over the CPUs (every process, the kernel's included)."""
    return _busy_ticks([b - a for a, b in zip(start, end, strict=True)]) / os.sysconf(
        "SC_CLK_TCK")


def _busy_ticks(d: list[int]) -> int:
    """Busy time of a :func:`cpu_times` difference: user, nice, system, irq and softirq."""
    user, nice, system, _idle, _iowait, irq, softirq, _steal = d
    return user + nice + system + irq + softirq


def machine_record(*, probe: bool = True) -> dict[str, Any]:
    """The record at the start of a run (call :func:`finish` at its end)."""
    record: dict[str, Any] = {
        "cpu": _cpu_model(),
        "cpus": os.cpu_count(),
        "load_avg_1m_start": round(os.getloadavg()[0], 2),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "blas": blas_info(),
    }
    if probe:
        record["speed_probe"] = speed_probe()
        record["cross_core_ns_start"] = cross_core_ns()
    record[_CPU_TIMES_START] = cpu_times()  # after the probe: the run's time only
    return record


def finish(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` with the 1-minute load average at the end of the run, how the machine's
    CPU time was spent since :func:`machine_record` (``cpu_time``, where ``/proc/stat`` can
    be read), the cores' distance again (``cross_core_ns_end``, where it was taken at the
    start), and the CPU the learner's kernels were compiled for (``kernels_cpu``, where
    they ran: :func:`.learner.jit_target.compiled_for`)."""
    record["load_avg_1m_end"] = round(os.getloadavg()[0], 2)
    if "cross_core_ns_start" in record:
        record["cross_core_ns_end"] = cross_core_ns()
    start, end = record.pop(_CPU_TIMES_START, None), cpu_times()
    split = cpu_time_split(start, end) if start is not None and end is not None else None
    if split is not None:
        record["cpu_time"] = split
    if _KERNELS in sys.modules:  # the learner ran here: what its kernels were compiled for
        from roger_daemon.learner.engine.jit_target import compiled_for

        kernels = compiled_for()
        if kernels is not None:  # docs/reproducibility.md
            record["kernels_cpu"] = kernels
    return record


def describe(record: dict[str, Any]) -> str:
    """One line for a benchmark's table: CPU, load start -> end, the speed probe, the cores'
    distance start -> end, stolen CPU time, what the learner's kernels were compiled for."""
    text = f"{record['cpu']}, {record['cpus']} CPUs, load {record['load_avg_1m_start']}"
    if "load_avg_1m_end" in record:
        text += f" -> {record['load_avg_1m_end']}"
    if "speed_probe" in record:
        probe = record["speed_probe"]
        text += f", speed probe: Python {probe['python_ms']} ms, memory {probe['memory_ms']} ms"
    if record.get("cross_core_ns_start") is not None:
        text += f", cross-core round trip {record['cross_core_ns_start']}"
        if record.get("cross_core_ns_end") is not None:
            text += f" -> {record['cross_core_ns_end']}"
        text += " ns"
    if "cpu_time" in record:
        text += f", CPU stolen {record['cpu_time']['steal_percent']} %"
    if "kernels_cpu" in record:
        text += f", kernels for {record['kernels_cpu']}"
    return text

"""Test-suite set-up shared by every test module."""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest

from roger_daemon.blas import pin_blas_threads

# The learner runs with one BLAS thread wherever it runs (roger_daemon/blas.py); tests that
# learn in-process get the same pinning as every `roger` command, whatever the shell says.
pin_blas_threads(1)


@pytest.fixture(autouse=True)
def _restore_learner_threads() -> Iterator[None]:
    """A test that sets the learner's thread count (``jit.set_threads``) gets it reset after."""
    from roger_daemon.learner.engine import jit, jit_threads

    before = jit_threads._threads
    yield
    if jit_threads._threads != before:
        jit.set_threads(before)


@pytest.fixture(scope="session", autouse=True)
def _learner_kernels_compiled() -> None:
    """Compile the learner's kernels into numba's on-disk cache before the first test (each
    test process does; it took ~45 s on a 2-core AMD EPYC from a clean clone): the daemons,
    workers and commands the tests start then load them instead of compiling them inside
    their start-up deadlines."""
    from roger_daemon.learner.engine import jit

    jit.warm_up()


#: The longest tests of `make test`, longest first (``--durations``, 2026-12-03: 10-40 s each
#: on 2 cores at load 2-4, the short demo ~40 s when its stages do not stall; docs/testing.md).
#: They are run first, dealt in turn to the start of each xdist worker's share: a long test
#: begun last leaves the other worker idle until it ends, and stealing (``--dist
#: worksteal``) moves only tests that have not started. A name that no longer matches just
#: loses its place; a prefix matches every test it starts.
LONG_FIRST = (
    "tests/test_demo.py::test_short_demo",
    "tests/test_bench_fleet.py::test_bench_fleet_runs_both_phases",
    "tests/test_teach_browser.py::test_teach_in_a_browser",
    "tests/test_durability_perception_first.py::",
    "tests/test_script_parallel_bound.py::test_step_reads_every_version",
    "tests/test_recovery_integration.py::test_sigkill_twice",
    "tests/test_standby_takeover.py::test_kill_9_of_the_primary",
    "tests/test_durability.py::test_kill_9_loses_no_acknowledged_pair",
    "tests/test_workers.py::test_with_workers_only_the_workers_load_the_compiled_kernels",
    "tests/test_experiment_streams.py::test_two_streams_run_end_to_end",
    "tests/test_experiment_inprocess.py::test_the_in_process_path_writes_results",
    "tests/test_sim_world.py::test_kick_distance_and_heading_match_the_calibration",
    "tests/test_play_node.py::test_the_robot_moves_under_roger_play_on_loopback",
    "tests/test_script_shared_base.py::test_shared_base_split_is_exact",
    "tests/test_disk_full.py::test_a_full_disk_stops_learning",
    "tests/test_router_stall.py::test_a_block_burst_to_a_busy_subscriber",
    "tests/test_daemon_integration.py::test_realtime_predictions_at_30_hz",
    "tests/test_daemon_integration.py::test_sigterm_checkpoints_and_restart",
    "tests/test_standby_takeover.py::test_the_standby_takes_over",
    "tests/test_workers.py::test_worker_equals_in_process_model_bit_for_bit",
    "tests/test_examples.py::test_your_own_robot_learns_and_predicts",
)


def _long_rank(nodeid: str) -> int:
    return next((i for i, p in enumerate(LONG_FIRST) if nodeid.startswith(p)), len(LONG_FIRST))


def _worksteal_shares(n_items: int, workers: int) -> list[int]:
    """How many tests each worker gets first: worksteal hands the pending tests out in
    order, ``len(pending) // workers_left`` each (xdist/scheduler/worksteal.py)."""
    shares, left = [], n_items
    for i in range(workers):
        shares.append(left // (workers - i))
        left -= shares[-1]
    return shares


def order_long_first(items: list[Any], workers: int) -> list[Any]:
    """``items`` with the :data:`LONG_FIRST` tests dealt round-robin to the front of each of
    ``workers`` consecutive shares, the rest in their collected order after them. The tests
    of one entry stay together on one worker (the two of ``test_step_reads_every_version``
    compile the same kernel: side by side on two workers, each compiled it, 53 s apiece).

    >>> class T:
    ...     def __init__(self, nodeid): self.nodeid = nodeid
    ...     def __repr__(self): return self.nodeid.split("::")[-1].replace("_both_phases", "")
    >>> ts = [T(f"tests/t.py::t{i}") for i in range(4)] + [
    ...     T("tests/test_demo.py::test_short_demo"),
    ...     T("tests/test_bench_fleet.py::test_bench_fleet_runs_both_phases[a]"),
    ...     T("tests/test_bench_fleet.py::test_bench_fleet_runs_both_phases[b]")]
    >>> order_long_first(ts, 2)
    [test_short_demo, t0, t1, test_bench_fleet_runs[a], test_bench_fleet_runs[b], t2, t3]
    >>> order_long_first(ts, 1)[:3]
    [test_short_demo, test_bench_fleet_runs[a], test_bench_fleet_runs[b]]
    """
    workers = max(1, workers)
    groups: list[list[Any]] = [[] for _ in range(len(LONG_FIRST) + 1)]
    for it in items:
        groups[_long_rank(it.nodeid)].append(it)
    rest = groups.pop()
    heads: list[list[Any]] = [[] for _ in range(workers)]
    for i, group in enumerate(g for g in groups if g):
        heads[i % workers] += group
    out: list[Any] = []
    for head, share in zip(heads, _worksteal_shares(len(items), workers), strict=True):
        take = max(0, share - len(head))
        out += head + rest[:take]
        rest = rest[take:]
    return out + rest


@pytest.hookimpl(trylast=True)  # after ``-m 'not slow'`` deselected: the shares are of what runs
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Run the :data:`LONG_FIRST` tests first, spread over the xdist workers (every worker
    collects, and must order, the same way: xdist tells each of them the count)."""
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")
    items[:] = order_long_first(items, int(workers) if workers.isdigit() else 1)

"""One learner worker process on its own: its frames and arrays, its start-up
(:mod:`roger_daemon.daemon.worker`; the daemon with workers: tests/test_workers.py)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.daemon.worker import pack_arrays, read_frame, unpack_arrays, write_frame
from roger_daemon.learner import RogerParams
from roger_daemon.learner.synthetic import subtask_stream

STREAM = subtask_stream(20)


def test_arrays_round_trip_without_pickle() -> None:
    arrays = {"f": np.arange(6.0).reshape(2, 3), "i": np.arange(4, dtype=np.int32),
              "s": np.array('{"a": 1}'), "e": np.zeros((0, 5))}
    back = unpack_arrays(pack_arrays(arrays))
    assert array_digest(back) == array_digest(arrays)
    with pytest.raises(TypeError):
        pack_arrays({"o": np.array([object()])})
    with pytest.raises(ValueError):
        unpack_arrays({"o": {"t": "|O", "s": [1], "b": b"\0" * 8}})
    with pytest.raises(ValueError):
        unpack_arrays({"f": {"t": "<f8", "s": [3], "b": b"\0" * 8}})


@pytest.mark.parametrize("threads", [None, 2])
def test_a_worker_process_warms_the_learner_kernels_up_when_it_loads(threads: int | None
                                                                     ) -> None:
    """A fresh worker process compiles (or loads from numba's cache) the learner's kernels at
    ``load``, not inside a robot's first steps (a first use mid-run stalled a step for
    milliseconds to seconds): its load reply counts the compiled signatures, 0 in a process
    that never warmed them up.  It learns on ``--threads`` threads (1 unless given; at most
    numba's count)."""
    import numba

    extra = [] if threads is None else ["--threads", str(threads)]
    proc = subprocess.Popen([sys.executable, "-m", "roger_daemon.daemon.worker", *extra],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert proc.stdin is not None and proc.stdout is not None
        write_frame(proc.stdin, {"op": "load", "robot": "aibo", "x_dim": STREAM.x.shape[1],
                                 "y_dim": STREAM.y.shape[1], "model": "roger", "seed": 0,
                                 "params": RogerParams().to_mapping(), "state": None,
                                 "codes": None})
        reply = read_frame(proc.stdout)
        assert reply is not None and reply["n"] == 0
        assert reply["kernels"] > 0
        assert reply["threads"] == min(threads or 1, numba.config.NUMBA_NUM_THREADS)
        write_frame(proc.stdin, {"op": "stop"})
        assert read_frame(proc.stdout) == {}
        assert proc.wait(timeout=120) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_robots_share_the_cores_out_among_their_workers() -> None:
    """``threads_per_worker``: the usable cores divided by the worker processes, at least
    one."""
    import os

    from roger_daemon.daemon.worker_procs import threads_per_worker

    cores = len(os.sched_getaffinity(0))
    assert threads_per_worker(1) == cores
    assert threads_per_worker(cores) == 1
    assert threads_per_worker(8 * cores + 1) == 1
    assert threads_per_worker(0) == cores


def test_a_worker_refuses_fewer_than_one_thread() -> None:
    out = subprocess.run([sys.executable, "-m", "roger_daemon.daemon.worker", "--threads", "0"],
                         capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert out.returncode == 2
    assert "--threads must be an integer >= 1, got 0" in out.stderr
    assert "Traceback" not in out.stderr


def test_collections_held_for_idle_moments_follow_the_interpreters_own_rule() -> None:
    """After loading its model a worker freezes what survives and raises the automatic
    thresholds (a backstop); at idle moments it then collects the oldest generation whose
    count passed the interpreter's threshold (roger_daemon/daemon/gc_policy.py)."""
    import gc

    from roger_daemon.daemon.gc_policy import (
        GC_BACKSTOP,
        collect_when_idle,
        freeze_survivors,
        hold_collections,
    )

    before = gc.get_threshold()
    try:
        thresholds = hold_collections()
        assert thresholds == before
        assert gc.get_threshold() == tuple(t * GC_BACKSTOP for t in before)
        assert gc.get_freeze_count() > 0
        frozen = gc.get_freeze_count()
        loaded = [[i] for i in range(100)]  # another robot's model, loaded later
        assert freeze_survivors() == before  # thresholds not raised a second time
        assert gc.get_threshold() == tuple(t * GC_BACKSTOP for t in before)
        assert gc.get_freeze_count() >= frozen + len(loaded)
        gc.collect()
        assert collect_when_idle(thresholds) is None  # nothing due right after a collection
        junk = [[i] for i in range(thresholds[0] + 50)]  # young containers past threshold 0
        assert collect_when_idle(thresholds) == 0
        assert gc.get_count()[0] < thresholds[0] and gc.get_count()[1] >= 1
        for _ in range(thresholds[1] + 1):  # past threshold 1: the middle generation is due
            gc.collect(0)
        assert collect_when_idle(thresholds) == 1 and gc.get_count()[1] == 0
        del junk
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)

"""The learned transitions' compiled path (roger_daemon/fsm/jit_fsm.py) against the readable
numpy code it replaces (docs/autonomy.md, *Cost*): the same state dict bit for bit, the same
choices, the Student-t terms equal to rounding."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from roger_daemon.bench.learner import load_stream
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.fsm import LearnedFSM, aibo_memory
from roger_daemon.fsm.online import newest_assignment
from roger_daemon.learner import Roger

POINTS = 500


@pytest.fixture(scope="module")
def taught() -> tuple[list[tuple[np.ndarray, np.ndarray, int]], list[tuple[np.ndarray, object]]]:
    """The first AIBO pairs with the MAP expert ROGER gave each (as RogerFSM teaches them),
    and every 10th next input with its multimap table."""
    stream = load_stream("aibo", POINTS, 0, [])
    model = Roger(stream.x.shape[1], stream.y.shape[1], stream.params, seed=0)
    pairs, queries = [], []
    for i in range(POINTS):
        model.learn_one(stream.x[i], stream.y[i])
        pairs.append((stream.x[i], stream.y[i], newest_assignment(model)))
        if i % 10 == 0:
            q = stream.x[min(i + 1, POINTS - 1)]
            queries.append((q, model.predict_table(q)[1]))
    return pairs, queries


def _teach(fast: bool, pairs: list[tuple[np.ndarray, np.ndarray, int]]) -> LearnedFSM:
    fsm = LearnedFSM(aibo_memory(), fast=fast)
    for i, (x, y, state) in enumerate(pairs):
        # an episode start now and then, and a tick without an expert: every branch
        fsm.observe(x, y, -1 if i % 97 == 5 else state, episode_start=i % 150 == 0,
                    learn_start=i % 2 == 0)
    return fsm


def test_learning_is_the_readable_code_bit_for_bit(taught) -> None:  # type: ignore[no-untyped-def]
    pairs, _ = taught
    fast, plain = _teach(True, pairs), _teach(False, pairs)
    a, b = fast.state_dict(), plain.state_dict()
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes(), k
    assert array_digest(a) == array_digest(b)
    assert len(fast.transitions.count) > 10  # a stream with many pairs, not a trivial one


def test_choices_and_commands_are_the_readable_code_s(taught) -> None:  # type: ignore[no-untyped-def]
    pairs, queries = taught
    fast, plain = _teach(True, pairs), _teach(False, pairs)
    rows = []
    for fsm in (fast, plain):
        fsm.reset()
        out = []
        for q, table in queries:
            cmd = fsm.act(q, table)
            out.append((fsm.state, cmd.tobytes(), fsm._act.memory.buffer.tobytes()))
        rows.append(out)
    assert rows[0] == rows[1]
    assert len({s for s, _, _ in rows[0]}) > 1  # the robot changed state on the way


def test_the_student_t_terms_equal_the_readable_ones_to_rounding(taught) -> None:  # type: ignore[no-untyped-def]
    from roger_daemon.fsm import jit_fsm

    pairs, _ = taught
    tr = _teach(True, pairs).transitions
    buf = tr._buf
    for prev in tr.sources():
        rows = tr.source_rows(prev)
        for r in rows:
            jit_fsm.predictive(int(r), buf["count"], buf["lam"], buf["linv"], buf["lnorm"],
                               tr.kappa0, tr.nu0)
        _, mu, prec, lognorm, half = tr._predictives(rows.tolist())
        c = buf["lnorm"][rows, 3]
        for k, r in enumerate(rows):
            w = buf["linv"][r].T  # stored transposed: L^-1
            np.testing.assert_allclose(w.T @ w / c[k], prec[k], rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(buf["lnorm"][rows, 0], lognorm, rtol=1e-10)
        np.testing.assert_array_equal(buf["lnorm"][rows, 1:3], half)


def test_the_kernel_remainder_is_ieee_s() -> None:
    from roger_daemon.fsm.jit_fsm import _remainder

    rng = np.random.default_rng(3)
    xs = list(rng.uniform(-4 * math.pi, 4 * math.pi, 2000)) + [
        math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 0.0, -0.0, 2 * math.pi, 7.0]
    for x in xs:
        assert _remainder(x, math.tau) == math.remainder(x, math.tau), x
    for x in (0.5, 1.5, 2.5, -2.5, -3.5):  # the ties go to the even quotient
        assert _remainder(x, 1.0) == math.remainder(x, 1.0), x


def test_a_fast_model_with_non_finite_features_is_refused() -> None:
    fsm = LearnedFSM(aibo_memory())
    x, y = np.zeros(23), np.zeros(9)
    fsm.observe(x, y, 0)
    fsm.observe(x, y, 0)  # the pair (0, 0) is known: the kernel's own update refuses
    from protocols.aibo import PERCEPTION_NAMES

    bad = x.copy()
    bad[PERCEPTION_NAMES.index("head_pan")] = math.nan  # a proprioceptive feature
    plain = LearnedFSM(aibo_memory(), fast=False)
    for fsm_ in (fsm, plain):
        with pytest.raises(ValueError, match="finite"):
            fsm_.observe(bad, y, 0)


_MISSES = """
import json
from roger_daemon.fsm import jit_fsm
jit_fsm.warm()
kernels = [jit_fsm.observe, jit_fsm.choose]
print(json.dumps({"misses": sum(sum(k.stats.cache_misses.values()) for k in kernels),
                  "hits": sum(sum(k.stats.cache_hits.values()) for k in kernels)}))
"""


@pytest.mark.slow
def test_roger_compile_fills_the_cache_of_the_transitions_kernels(tmp_path: Path) -> None:
    """Oracle: numba's cache statistics. After ``roger compile`` into an empty cache, a fresh
    process loads the transitions' kernels and compiles none."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-m", "roger_daemon", "compile"], capture_output=True,
                         text=True, cwd=root, timeout=600, env=env)
    assert out.returncode == 0, out.stderr
    probe = subprocess.run([sys.executable, "-c", _MISSES], capture_output=True, text=True,
                           cwd=root, timeout=600, env=env, check=True)
    got = json.loads(probe.stdout.strip().splitlines()[-1])
    assert got == {"misses": 0, "hits": 2}

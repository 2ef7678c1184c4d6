"""``scripts/learner_digests.py``: the digests that prove a change to the learner changed no
float are a function of what was learned (the same runs give the same digests, another seed
or one more pair another), its state digest is the checkpoints' own, and bad arguments exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
from script_testing import load_script

from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.learner import Roger

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "learner_digests.py"


def _script() -> ModuleType:
    return load_script("learner_digests", SCRIPT)


def test_the_digests_are_those_of_what_was_learned() -> None:
    ld = _script()
    first = ld.digests(40)
    assert set(first) == {"synthetic", "unimap", "aibo", "levers"}
    assert first == ld.digests(40)  # deterministic
    assert all(len(d["state"]) == 64 and d["points"] == 40 for d in first.values())
    other_seed = ld.digests(40, runs=["synthetic"], seed=1)
    assert other_seed["synthetic"]["state"] != first["synthetic"]["state"]
    longer = ld.digests(41, runs=["aibo"])
    assert longer["aibo"]["state"] != first["aibo"]["state"]
    assert longer["aibo"]["answers"] != first["aibo"]["answers"]
    # the state digest is array_digest of the state dict, which a restored model reproduces
    stream = ld.load_stream("aibo", 40, ld.BENCH_SEED, [])
    model = Roger(stream.x.shape[1], stream.y.shape[1], stream.params, seed=0)
    for x, y in zip(stream.x, stream.y, strict=True):
        model.learn_one(x, y)
    restored = Roger.from_state_dict(model.state_dict())
    assert array_digest(restored.state_dict()) == first["aibo"]["state"]
    assert np.array_equal(restored.assignments(), model.assignments())


def test_bad_points_exit_2_naming_the_value() -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "--points", "0"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2 and "--points must be >= 1 (got 0)" in out.stderr
    assert "Traceback" not in out.stderr


def test_the_json_has_one_entry_per_run() -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "--points", "20", "--json"],
                         capture_output=True, text=True, timeout=600, check=True)
    got = json.loads(out.stdout)
    assert sorted(got) == ["aibo", "levers", "synthetic", "unimap"]
    assert got["unimap"]["experts"] == 1

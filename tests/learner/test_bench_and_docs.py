"""``roger bench learner`` output contract, the shipped stream, and the modules' doctests."""

from __future__ import annotations

import doctest
import importlib
import json
import sys

import numpy as np
import pytest

from roger_daemon.cli import main
from roger_daemon.learner.engine import jit
from roger_daemon.learner.synthetic import subtask_stream

MODULES = ["kernel", "sogp", "gate", "resampling", "roger", "unimap", "params", "synthetic",
           "evidence"]


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name: str) -> None:
    module = importlib.import_module(f"roger_daemon.learner.{name}")
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0


def test_bench_json_has_the_contract_keys(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "learner", "--json", "--points", "60", "--predict-every", "5"]) == 0
    res = json.loads(capsys.readouterr().out)
    for key in ("updates_per_s", "update_p99_ms", "predict_multimap_p99_ms", "experts",
                "unimap_updates_per_s", "machine", "params"):
        assert key in res
    assert res["points"] == 60 and res["d_x"] == 23 and res["d_y"] == 9
    assert res["updates_per_s"] > 0 and res["experts"] >= 1
    assert res["params"]["beta"] == 300 and res["params"]["alpha"] == 0.5
    # the learned transitions' cost beside the step: 60 updates, 12 ticks (every 5th step)
    tr = res["transitions"]
    assert tr["update_p50_ms"] > 0 and tr["tick_p50_ms"] > 0 and tr["step_mean_ms"] > 0
    assert tr["update_share_of_step"] == pytest.approx(
        tr["update_mean_ms"] / tr["step_mean_ms"], rel=0.01)


def test_bench_table_and_param_override(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "learner", "--points", "30", "--no-unimap", "--param", "beta=20",
                 "--param", "kernel_dim_scaling=grollman"]) == 0
    out = capsys.readouterr().out
    assert "updates/s (mean)" in out and "unimap" not in out
    assert "transitions update p50 / p99 ms" in out and "% of the mean step" in out
    assert main(["bench", "learner", "--points", "10", "--no-unimap", "--no-transitions"]) == 0
    assert "transitions" not in capsys.readouterr().out


def test_benchmark_stream_is_deterministic_and_shaped() -> None:
    a, b = subtask_stream(), subtask_stream()
    assert a.x.shape == (4000, 23) and a.y.shape == (4000, 9)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.y, b.y)
    assert np.bincount(a.labels).tolist() == [1000] * 4
    # subtasks 0 and 2 share their input distribution (the multimap): same hidden objects
    hidden0 = np.all(a.x[a.labels == 0, :18] < -0.9, axis=0)
    hidden2 = np.all(a.x[a.labels == 2, :18] < -0.9, axis=0)
    np.testing.assert_array_equal(hidden0, hidden2)
    assert not np.array_equal(hidden0, np.all(a.x[a.labels == 1, :18] < -0.9, axis=0))


def test_bench_aibo_stream_is_shipped_and_learned_with_the_daemon_defaults(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "learner", "--stream", "aibo", "--json", "--points", "25",
                 "--no-unimap", "--predict-every", "0"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["stream"] == "aibo" and res["points"] == 25 and res["d_x"] == 23
    assert res["params"]["theta_w"] == 10.0 and res["params"]["gp_prior_mean"] == "expert"
    assert res["params"]["input_weights"][-2:] == [0.0, 0.0]  # the AIBO profile


def test_bench_compare_refuses_an_unknown_revision(capsys: pytest.CaptureFixture[str]) -> None:
    """A revision git does not know exits 2 naming ``--compare``, before compiling anything."""
    assert main(["bench", "learner", "--points", "4", "--compare", "no-such-revision-xyz"]) == 2
    assert "--compare" in capsys.readouterr().err


# compiles the revision's kernels in a checkout of their own (~45 s on 2 cores): `make test-all`
@pytest.mark.slow
def test_bench_compare_runs_a_git_revision_beside_this_learner(
        capsys: pytest.CaptureFixture[str]) -> None:
    from roger_daemon.bench.learner_compare import reference_kernels
    from roger_daemon.bench.reference import RevisionError, load_reference

    try:
        load_reference("HEAD")
    except RevisionError as exc:  # not a git checkout (an installed wheel)
        pytest.skip(str(exc))
    assert main(["bench", "learner", "--stream", "aibo", "--points", "6", "--compare", "HEAD",
                 "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["bench"] == "learner-compare" and res["points"] == 6
    assert res["ref"]["updates_per_s"] > 0 and res["new"]["updates_per_s"] > 0
    assert res["speedup"] > 0 and isinstance(res["same_segmentation"], bool)
    assert main(["bench", "learner", "--points", "4", "--compare", "HEAD"]) == 0
    assert "speedup (new / REF updates/s)" in capsys.readouterr().out
    # the reference's batched kernels run on this learner's threads, not on their default
    assert main(["bench", "learner", "--stream", "aibo", "--points", "4", "--compare", "HEAD",
                 "--threads", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["learner_threads"] == 1
    ref_jit = reference_kernels(load_reference("HEAD")[0])
    assert ref_jit is not None and ref_jit.threads() == 1


def test_fleet_and_soak_feed_the_aibo_demonstrations_by_default() -> None:
    """``roger bench fleet`` and ``soak`` feed the recorded AIBO stream unless told otherwise."""
    import argparse

    from roger_daemon.bench import fleet, soak
    from roger_daemon.bench.streams import feed_stream

    for module in (fleet, soak):
        parser = argparse.ArgumentParser()
        module.configure(parser)
        assert parser.parse_args([]).stream == "aibo"
    aibo = feed_stream("aibo")
    assert aibo.x.shape == (1500, 23) and aibo.y.shape == (1500, 9)
    assert len(aibo.labels) == 1500 and {"kick", "trap"} <= set(aibo.labels)
    synthetic = feed_stream("synthetic", 50)
    assert synthetic.x.shape == (50, 23) and len(synthetic.labels) == 50
    with pytest.raises(ValueError, match="unknown stream"):
        feed_stream("nope")


def test_bandwidth_script_counts_the_compiled_passes_of_a_step() -> None:
    """scripts/learner_bandwidth.py (docs/fleet.md) wraps the compiled kernels by name: if
    they are renamed the counts go to zero, which this catches."""
    import subprocess
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "scripts" / "learner_bandwidth.py"
    out = subprocess.run([sys.executable, str(script), "--points", "160", "--json"],
                         capture_output=True, text=True, timeout=300, check=True)
    report = json.loads(out.stdout)
    passes = report["passes_per_step"]
    assert passes["expert_terms"] >= 1 and passes["projection"] >= 1
    # each distinct expert once a step: the stream's ~20 in one call of at most
    # EVALUATION_WIDTH (a wrong argument counted as the number of experts reads more)
    assert passes["expert_terms"] <= jit.EVALUATION_WIDTH
    assert report["beta"] == 300 and report["distinct_experts"] >= 1
    assert report["passes_ms_per_step"] > 0 and report["pass_us_out_of_cache"] > 0

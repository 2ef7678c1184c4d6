"""``roger experiment peers``: argument checks, the curve's order, the dataset the peers train
from, and (with the peers extra installed) a smoke run with LeRobot's ACT and Diffusion Policy
on a tiny budget (docs/peers.md)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simulator.experiment import peers, peers_data
from simulator.experiment.peers_policy import available, split_stats
from simulator.experiment.training import Demonstrations

ROOT = Path(__file__).resolve().parents[1]


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    peers.configure(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize("argv, named", [
    (["--policies", "act,bc"], "'act,bc'"),
    (["--steps", "act=0"], "'act=0'"),
    (["--steps", "vqbet=3"], "'vqbet=3'"),
    (["--curve", "ten"], "'ten'"),
    (["--curve", "0,10"], "'0,10'"),
    (["--batch-size", "0"], "--batch-size"),
    (["--start-poses", "no-such-file.toml"], "no-such-file.toml"),
])
def test_a_bad_argument_exits_2_naming_it(argv: list[str], named: str, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    assert peers.run(_args("--out", str(tmp_path / "o"), *argv)) == 2
    err = capsys.readouterr().err
    assert err.startswith("roger experiment peers: ") and named in err
    assert not (tmp_path / "o").exists()


def test_without_lerobot_the_command_says_how_to_install_it(tmp_path: Path) -> None:
    if not available():
        pytest.skip("LeRobot is installed here: the command runs instead")
    proc = subprocess.run([sys.executable, "-m", "roger_daemon", "experiment", "peers",
                           "--out", str(tmp_path / "o"), "--smoke"], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "make venv-peers" in proc.stderr and "Traceback" not in proc.stderr


def test_steps_and_curve_parse() -> None:
    assert peers.parse_steps(None, ["act"]) == {"act": peers.DEFAULT_STEPS["act"]}
    assert peers.parse_steps("7", ["act", "diffusion"]) == {"act": 7, "diffusion": 7}
    assert peers.parse_curve("none", 130) == []
    assert peers.parse_curve("130,10,500", 130) == [10, 130]


def _records(locations: int, shots: int) -> list[dict[str, object]]:
    # goal-scoring's order: location by location, shot by shot
    return [{"location": loc, "repetition": s, "success": True}
            for loc in range(locations) for s in range(shots)]


def _stream(records: list[dict[str, object]], ticks: int) -> Demonstrations:
    rng = np.random.default_rng(0)
    n = len(records) * ticks
    return Demonstrations(rng.normal(size=(n, 23)), rng.normal(size=(n, 9)),
                          [("seek", "kick")[i % 2] for i in range(n)],
                          np.repeat([int(r["location"]) for r in records], ticks),  # type: ignore[call-overload]
                          np.tile(np.arange(ticks), len(records)), 0)


def test_the_curve_goes_round_robin_over_locations() -> None:
    records = _records(3, 2)
    assert peers_data.curve_order(records) == [0, 2, 4, 1, 3, 5]
    assert peers_data.curve_episodes(records, 3) == [0, 2, 4]  # shot 0 of every location
    data = _stream(records, 4)
    kept = np.array([1, 2, 5, 9, 13, 17, 22], dtype=np.int64)
    stream, rank = peers_data.curve_stream(data, kept, records)
    # demonstration 0 (rank 0), 2 (rank 1), 4 (rank 2), 1 (rank 3), 3 (rank 4), 5 (rank 5)
    assert rank.tolist() == [0, 0, 1, 2, 3, 4, 5]
    assert np.array_equal(stream.x, data.x[[1, 2, 9, 17, 5, 13, 22]])
    assert np.all(np.diff(rank) >= 0)


def test_the_export_holds_every_tick_one_episode_per_demonstration(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    from roger_daemon.datasets import read_dataset

    records = _records(2, 2)
    data = _stream(records, 5)
    peers_data.export_stream(data, tmp_path / "ds")
    info = json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 4 and info["total_frames"] == 20 and info["fps"] == 30
    assert info["features"]["observation.state"]["dtype"] == "float32"
    back = read_dataset(tmp_path / "ds")
    assert back.episode.tolist() == np.repeat(np.arange(4), 5).tolist()
    assert np.allclose(back.x, data.x.astype(np.float32)) and back.label == data.labels


def test_the_statistics_split_as_the_inputs() -> None:
    stats = {"observation.state": {"mean": np.arange(23.0), "count": np.array([5])},
             "action": {"mean": np.zeros(9)}}
    out = split_stats(stats)
    assert out["observation.environment_state"]["mean"].tolist() == list(range(18))
    assert out["observation.state"]["mean"].tolist() == list(range(18, 23))
    assert out["observation.state"]["count"].tolist() == [5] and "action" in out


@pytest.mark.integration
def test_smoke_run_with_lerobot(tmp_path: Path) -> None:
    why = available()
    if why:
        pytest.skip(why)
    out = tmp_path / "peers"
    proc = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "experiment", "peers", "--out", str(out),
         "--smoke", "--episode-duration", "4", "--start-poses", "none", "--threads", "1"],
        capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    for name in ("act", "diffusion"):
        block = results["peers"][name]
        assert block["trials"] == 2 and block["incremental"] is False
        assert block["steps"] == peers.SMOKE_STEPS and block["train_cpu_s"] > 0
        assert block["infer_p99_ms"] >= block["infer_p50_ms"] > 0
        assert block["parameters"] > 0 and block["model_bytes"] > 0
        assert (out / "models" / name / "model.safetensors").is_file()
    curve = results["learning_curve"]
    assert [r["demonstrations"] for r in curve["act"]] == [1, 2]
    assert [r["demonstrations"] for r in curve["roger"]] == [1, 2]
    assert (out / "learning_curve.png").is_file()
    assert (out / "dataset" / "meta" / "info.json").is_file()

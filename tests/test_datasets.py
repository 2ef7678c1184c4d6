"""Datasets in and out (issue 56): roger log export --format lerobot|parquet|hdf5 and
roger log import; the LeRobot v3 layout; export -> import -> the same pairs."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from protocols import Action, aibo  # noqa: E402
from roger_daemon.cli import main as roger  # noqa: E402
from roger_daemon.datasets import Pairs, pairs_from_log, read_dataset  # noqa: E402
from roger_daemon.datasets.session import write_session  # noqa: E402
from roger_daemon.learner import RogerParams  # noqa: E402
from roger_daemon.profiles import RobotProfile  # noqa: E402

SESSIONS = sorted((Path(__file__).parent / "data" / "sessions").glob("*.mcap"))
FORMATS = ("lerobot", "parquet", "hdf5")
#: the fields of LeRobot v3's DatasetInfo (lerobot/datasets/utils.py; "tools" is optional)
INFO_FIELDS = {"codebase_version", "fps", "features", "total_episodes", "total_frames",
               "total_tasks", "chunks_size", "data_files_size_in_mb", "video_files_size_in_mb",
               "data_path", "video_path", "robot_type", "splits"}
#: LeRobot's DEFAULT_FEATURES (lerobot/utils/constants.py)
DEFAULT_FEATURES = {"timestamp": "float32", "frame_index": "int64", "episode_index": "int64",
                    "index": "int64", "task_index": "int64"}
EPISODE_COLUMNS = {"episode_index", "tasks", "length", "data/chunk_index", "data/file_index",
                   "dataset_from_index", "dataset_to_index", "meta/episodes/chunk_index",
                   "meta/episodes/file_index"}
ACTION_HAS_SOURCE = "source" in {f.name for f in dataclasses.fields(Action)}


def export(log: Path, fmt: str, out: Path) -> Path:
    assert roger(["log", "export", str(log), "--format", fmt, "--out", str(out)]) == 0
    return out if fmt == "lerobot" else out / f"{log.stem}.{fmt}"


def imported(dataset: Path, out: Path, *extra: str) -> Path:
    assert roger(["log", "import", str(dataset), "--out", str(out), *extra]) == 0
    (log,) = sorted(out.glob("roger-*.mcap"))
    return log


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("log", SESSIONS, ids=lambda p: p.stem)
def test_export_then_import_gives_the_same_pairs(log: Path, fmt: str, tmp_path: Path) -> None:
    original = pairs_from_log(log)
    assert len(original) > 300 and set(original.label) <= set(aibo.SUBTASKS)
    dataset = export(log, fmt, tmp_path / "out")
    assert read_dataset(dataset).same_pairs(original)
    session = imported(dataset, tmp_path / "session")
    back = pairs_from_log(session)
    assert back.same_pairs(original) and back.profile == original.profile
    assert back.fps == original.fps == 30.0 and back.robot == "aibo"
    # and again: the imported session exports to the same dataset content
    again = export(session, fmt, tmp_path / "again")
    assert read_dataset(again).same_pairs(original)


def test_the_imported_session_replays_into_the_model_the_daemon_learned(tmp_path: Path,
                                                                        capsys) -> None:
    """The import is a session the daemon's tools learn from: replay rebuilds the model."""
    log = SESSIONS[0]
    session = imported(export(log, "lerobot", tmp_path / "ds"), tmp_path / "session")
    capsys.readouterr()
    assert roger(["replay", str(log), "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    assert roger(["replay", str(session), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["decision_records"] and got["pairs_learned"] == want["pairs_learned"]
    assert got["expert_sizes"] == want["expert_sizes"] and got["params"] == want["params"]


def test_the_lerobot_export_follows_the_v3_layout(tmp_path: Path) -> None:
    log = SESSIONS[1]
    root = export(log, "lerobot", tmp_path / "ds")
    pairs = pairs_from_log(log)
    info = json.loads((root / "meta" / "info.json").read_text())
    assert set(info) == INFO_FIELDS and info["codebase_version"] == "v3.0"
    assert info["fps"] == 30 and info["video_path"] is None
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["total_frames"] == len(pairs) and info["total_tasks"] == 1
    assert info["splits"] == {"train": f"0:{info['total_episodes']}"}
    feats = info["features"]
    for name, dtype in DEFAULT_FEATURES.items():
        assert feats[name] == {"dtype": dtype, "shape": [1], "names": None}
    assert feats["observation.state"] == {"dtype": "float64", "shape": [23],
                                          "names": list(aibo.PERCEPTION_NAMES)}
    assert feats["action"]["names"] == list(aibo.ACTION_NAMES)
    data = pq.ParquetFile(root / "data" / "chunk-000" / "file-000.parquet")
    table = data.read()
    assert set(table.column_names) == set(feats)  # every feature is a column, and no other
    assert table.schema.field("observation.state").type == pa.list_(pa.float64(), 23)
    assert table.schema.field("action").type == pa.list_(pa.float64(), 9)
    assert table.schema.field("timestamp").type == pa.float32()
    n = table.num_rows
    assert table.column("index").to_pylist() == list(range(n))
    frame = np.array(table.column("frame_index").to_pylist())
    np.testing.assert_allclose(table.column("timestamp").to_numpy(), frame / 30.0, atol=1e-6)
    episodes = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    assert EPISODE_COLUMNS <= set(episodes.column_names)
    assert data.num_row_groups == episodes.num_rows == info["total_episodes"]
    eps = episodes.to_pydict()
    assert eps["dataset_from_index"][0] == 0 and eps["dataset_to_index"][-1] == n
    assert eps["length"] == [b - a for a, b in zip(eps["dataset_from_index"],
                                                   eps["dataset_to_index"], strict=True)]
    tasks = pq.read_table(root / "meta" / "tasks.parquet")
    pandas_meta = json.loads(tasks.schema.metadata[b"pandas"])
    assert pandas_meta["index_columns"] == ["task"]  # LeRobot looks tasks up by their text
    assert tasks.column("task_index").to_pylist() == [0]
    assert eps["tasks"] == [tasks.column("task").to_pylist()] * episodes.num_rows
    stats = json.loads((root / "meta" / "stats.json").read_text())
    for key, d in (("observation.state", 23), ("action", 9)):
        assert {"min", "max", "mean", "std", "count", "q01", "q50", "q99"} <= set(stats[key])
        assert len(stats[key]["mean"]) == d and stats[key]["count"] == [n]
    x = np.stack(table.column("observation.state").to_numpy(zero_copy_only=False))
    np.testing.assert_array_equal(stats["observation.state"]["max"], x.max(0))


def made_up_pairs() -> Pairs:
    """Three episodes of a 3-D -> 2-D robot, with teacher and robot sources."""
    rng = np.random.default_rng(3)
    n = 50
    profile = RobotProfile(name="cart", x_names=("px", "py", "load"), y_names=("vx", "vy"),
                           x_ranges=((-1.0, 1.0),) * 3, y_ranges=((-2.0, 2.0),) * 2)
    return Pairs(x=rng.normal(size=(n, 3)), y=rng.normal(size=(n, 2)),
                 tick=np.arange(100, 100 + n), episode=np.repeat([0, 1, 2], [20, 10, 20]),
                 label=["push" if i % 3 else "pull" for i in range(n)],
                 source=["teacher" if i < 30 else "robot" for i in range(n)],
                 profile=profile, fps=20.0, robot="cart", task="push the cart")


@pytest.mark.parametrize("fmt", FORMATS)
def test_episodes_names_sources_and_fps_survive_every_format(fmt: str, tmp_path: Path) -> None:
    pairs = made_up_pairs()
    log = write_session(pairs, tmp_path / "log", params=RogerParams().for_dims(3))
    from_log = pairs_from_log(log)
    want_source = pairs.source if ACTION_HAS_SOURCE else [""] * len(pairs)
    assert from_log.episodes == 3 and from_log.label == pairs.label
    assert from_log.source == want_source and from_log.fps == 20.0
    dataset = export(log, fmt, tmp_path / "out")
    back = read_dataset(dataset)
    assert back.same_pairs(from_log) and back.profile.x_names == ("px", "py", "load")
    assert back.fps == 20.0 and back.robot == "cart"
    if fmt == "lerobot":
        info = json.loads((dataset / "meta" / "info.json").read_text())
        assert info["fps"] == 20 and info["total_episodes"] == 3
        assert info["features"]["action"]["names"] == ["vx", "vy"]


def test_the_hdf5_export_follows_robomimics_layout(tmp_path: Path) -> None:
    """Read with h5py alone, as robomimic's SequenceDataset does: data/demo_<e> sorted by
    number, attrs num_samples and total, obs/<key>, actions, rewards, dones, env_args JSON."""
    h5py = pytest.importorskip("h5py")
    pairs = made_up_pairs()
    log = write_session(pairs, tmp_path / "log", params=RogerParams().for_dims(3))
    path = export(log, "hdf5", tmp_path / "out")
    with h5py.File(path, "r") as f:
        data = f["data"]
        demos = sorted(data, key=lambda k: int(k[5:]))
        assert demos == ["demo_0", "demo_1", "demo_2"] and data.attrs["total"] == len(pairs)
        env = json.loads(data.attrs["env_args"])
        assert {"env_name", "type", "env_kwargs"} <= set(env) and env["env_name"] == "cart"
        starts = [0, 20, 30, 50]
        for e, name in enumerate(demos):
            demo, (a, b) = data[name], starts[e:e + 2]
            assert demo.attrs["num_samples"] == b - a
            np.testing.assert_array_equal(demo["obs/state"][()], pairs.x[a:b])
            np.testing.assert_array_equal(demo["actions"][()], pairs.y[a:b])
            assert demo["dones"][()].tolist() == [0] * (b - a - 1) + [1]
            assert demo["rewards"].shape == (b - a,) and not demo["rewards"][()].any()


def test_the_parquet_export_has_a_named_column_per_entry(tmp_path: Path) -> None:
    """docs/datasets.md: one row per pair, x.<perception name> and y.<action name> columns
    (``df["x.load"]`` in pandas), the episode and frame indices, the subtask and source."""
    pairs = made_up_pairs()
    log = write_session(pairs, tmp_path / "log", params=RogerParams().for_dims(3))
    table = pq.read_table(export(log, "parquet", tmp_path / "out"))
    assert {"index", "episode_index", "frame_index", "timestamp", "tick", "subtask",
            "source", "x.px", "x.py", "x.load", "y.vx", "y.vy"} <= set(table.column_names)
    np.testing.assert_array_equal(table.column("x.load").to_numpy(), pairs.x[:, 2])
    np.testing.assert_array_equal(table.column("y.vy").to_numpy(), pairs.y[:, 1])
    assert table.column("episode_index").to_pylist() == pairs.episode.tolist()
    assert table.column("subtask").to_pylist() == pairs.label
    assert json.loads(table.schema.metadata[b"roger"])["fps"] == 20.0


def test_an_episode_boundary_is_where_the_simulator_started_an_episode(tmp_path: Path) -> None:
    pairs = made_up_pairs()
    log = write_session(pairs, tmp_path / "log", params=RogerParams().for_dims(3))
    back = pairs_from_log(log)
    np.testing.assert_array_equal(back.episode, pairs.episode)
    np.testing.assert_array_equal(back.frame_index()[[0, 19, 20, 29, 30]], [0, 19, 0, 9, 0])


def test_a_foreign_lerobot_dataset_without_roger_columns_imports(tmp_path: Path) -> None:
    """Another program's v3 dataset: float32 vectors, no meta/roger.json, no roger.* columns;
    the names come from info.json and the learner settings from --preset."""
    root = export(SESSIONS[0], "lerobot", tmp_path / "ds")
    table = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet")
    table = table.drop(["roger.tick", "roger.subtask", "roger.source"])
    pq.write_table(table, root / "data" / "chunk-000" / "file-000.parquet")
    (root / "meta" / "roger.json").unlink()
    info = json.loads((root / "meta" / "info.json").read_text())
    for k in ("roger.tick", "roger.subtask", "roger.source"):
        del info["features"][k]
    info["robot_type"] = "so100 follower"
    (root / "meta" / "info.json").write_text(json.dumps(info))
    session = imported(root, tmp_path / "session", "--seed", "3")
    back = pairs_from_log(session)
    want = pairs_from_log(SESSIONS[0])
    np.testing.assert_array_equal(back.x, want.x)
    assert back.robot == "so100_follower" and back.label == [""] * len(want)
    assert back.profile.x_names == aibo.PERCEPTION_NAMES
    np.testing.assert_array_equal(back.tick, np.arange(len(want)))


def test_a_foreign_datasets_names_given_as_a_map_are_kept(tmp_path: Path) -> None:
    """Datasets converted from LeRobot's older versions name entries {"motors": [...]}."""
    root = export(SESSIONS[0], "lerobot", tmp_path / "ds")
    (root / "meta" / "roger.json").unlink()
    info = json.loads((root / "meta" / "info.json").read_text())
    info["features"]["observation.state"]["names"] = {"motors": list(aibo.PERCEPTION_NAMES)}
    info["features"]["action"]["names"] = {"motors": list(aibo.ACTION_NAMES)}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    back = read_dataset(root)
    assert back.profile.x_names == aibo.PERCEPTION_NAMES
    assert back.profile.y_names == aibo.ACTION_NAMES


def test_float32_export_for_lerobot_policies(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    assert roger(["log", "export", str(SESSIONS[0]), "--format", "lerobot", "--dtype",
                  "float32", "--out", str(out)]) == 0
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["features"]["observation.state"]["dtype"] == "float32"
    back, want = read_dataset(out), pairs_from_log(SESSIONS[0])
    np.testing.assert_array_equal(back.x, want.x.astype(np.float32).astype(np.float64))


def test_bad_inputs_and_outputs_are_refused_and_nothing_is_overwritten(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "mine.txt").write_text("keep")
    assert roger(["log", "export", str(SESSIONS[0]), "--format", "lerobot",
                  "--out", str(busy)]) == 2
    assert "not empty" in capsys.readouterr().err and (busy / "mine.txt").read_text() == "keep"
    out = tmp_path / "pq"
    export(SESSIONS[0], "parquet", out)
    assert roger(["log", "export", str(SESSIONS[0]), "--format", "parquet",
                  "--out", str(out)]) == 2
    assert "pass --force" in capsys.readouterr().err
    assert roger(["log", "import", str(tmp_path / "nothing")]) == 1
    assert "no such file or directory" in capsys.readouterr().err
    assert roger(["log", "import", str(busy)]) == 1
    assert "not a LeRobot dataset" in capsys.readouterr().err
    assert roger(["log", "export", str(SESSIONS[0]), "--format", "parquet", "--profile",
                  "nonesuch"]) == 2
    assert "no shipped robot profile 'nonesuch'" in capsys.readouterr().err


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_lerobots_own_loader_reads_the_export(dtype: str, tmp_path: Path) -> None:
    """LeRobot's ``LeRobotDataset`` (0.4.4, the ``peers`` extra: ``make venv-peers``, then
    ``.venv-peers/bin/python -m pytest tests/test_datasets.py``) loads ``roger log export
    --format lerobot`` from disk: every frame's state, action, indices, timestamp and task,
    and the episode ranges its ``delta_timestamps`` pad at (a chunk of actions never runs
    into the next episode). Skipped where LeRobot is not installed; the layout test above
    checks the same files against LeRobot's published v3 layout everywhere."""
    pytest.importorskip("lerobot")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    pairs = made_up_pairs()  # three episodes at 20 fps, a 3-D -> 2-D profile
    log = write_session(pairs, tmp_path / "log", params=RogerParams().for_dims(3))
    want = pairs_from_log(log)
    root = tmp_path / "ds"
    assert roger(["log", "export", str(log), "--format", "lerobot", "--dtype", dtype,
                  "--out", str(root)]) == 0
    task = pq.read_table(root / "meta" / "tasks.parquet").column("task")[0].as_py()
    step = 1 / want.fps
    ds = LeRobotDataset("roger/export", root=root, delta_timestamps={"action": [0.0, step]})
    assert len(ds) == len(want) and ds.num_episodes == want.episodes == 3
    assert ds.fps == 20 and ds.meta.features["observation.state"]["names"] == ["px", "py",
                                                                                "load"]
    frame = want.frame_index()
    ends = {int(i) for i in np.flatnonzero(np.diff(want.episode))} | {len(want) - 1}
    for i in range(len(want)):
        item = ds[i]
        np.testing.assert_allclose(item["observation.state"].double().numpy(),
                                   want.x[i].astype(dtype), rtol=1e-6)
        np.testing.assert_allclose(item["action"][0].double().numpy(),
                                   want.y[i].astype(dtype), rtol=1e-6)
        assert int(item["episode_index"]) == want.episode[i] and int(item["index"]) == i
        assert int(item["frame_index"]) == frame[i] and item["task"] == task
        assert float(item["timestamp"]) == pytest.approx(frame[i] * step, abs=1e-5)
        assert bool(item["action_is_pad"][1]) == (i in ends)  # the episode's last frame

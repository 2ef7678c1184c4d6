"""LeRobot dataset v3.0 (``codebase_version`` ``"v3.0"``): write and read, with pyarrow only.

The layout is LeRobot's (``lerobot/datasets/utils.py`` and ``dataset_metadata.py`` of
huggingface/lerobot, read at its v3.0 format; ``docs/datasets.md`` lists what is checked)::

    meta/info.json                      features (dtype, shape, names), fps, totals, templates
    meta/stats.json                     per feature: min, max, mean, std, count, q01 .. q99
    meta/tasks.parquet                  task text (the pandas index "task") -> task_index
    meta/episodes/chunk-000/file-000.parquet   one row per episode: length, tasks, the
                                        frame range (dataset_from_index, dataset_to_index),
                                        where its rows are (data/chunk_index, data/file_index)
    data/chunk-000/file-000.parquet     one row per frame, one row group per episode
    meta/roger.json                     ROGER's own: robot, profile, learner params, seed

Frame columns: ``observation.state`` (the perception, named by the robot profile),
``action``, ``timestamp`` (frame_index / fps), ``frame_index``, ``episode_index``, ``index``,
``task_index``, and ROGER's ``roger.tick`` (the tick the pair was sent with),
``roger.subtask`` (the action's label) and ``roger.source`` (``"teacher"``/``"robot"``/"").
Vectors are float64 by default, so that reading the dataset back gives the very pairs
(``dtype="float32"``: LeRobot's usual, for policies that need it).

:func:`read_lerobot` reads any v3 dataset's ``observation.state`` and ``action`` (or the
features named), its episodes and tasks; ROGER's columns where present.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.datasets.pairs import FloatArray, Pairs
from roger_daemon.datasets.tables import column_array, require_pyarrow, stats_of
from roger_daemon.profiles import RobotProfile, generic_profile

__all__ = ["CODEBASE_VERSION", "read_lerobot", "write_lerobot"]

CODEBASE_VERSION = "v3.0"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
#: LeRobot's DEFAULT_FEATURES (lerobot/utils/constants.py)
DEFAULT_FEATURES: dict[str, dict[str, Any]] = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
ROGER_FEATURES: dict[str, dict[str, Any]] = {
    "roger.tick": {"dtype": "int64", "shape": [1], "names": None},
    "roger.subtask": {"dtype": "string", "shape": [1], "names": None},
    "roger.source": {"dtype": "string", "shape": [1], "names": None},
}
DTYPES = ("float64", "float32")


def _tasks_table(tasks: list[str]) -> Any:
    """``meta/tasks.parquet`` as pandas writes it: the ``task`` text is the frame's index
    (LeRobot reads it with ``pd.read_parquet`` and looks tasks up by ``tasks.loc[text]``)."""
    pa = require_pyarrow()
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                            "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": "task", "field_name": "task", "pandas_type": "unicode",
             "numpy_type": "object", "metadata": None}],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()),
                      "task": pa.array(tasks, pa.string())})
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def _frames(pairs: Pairs, dtype: str) -> Any:
    pa = require_pyarrow()
    n, (dx, dy) = len(pairs), (pairs.profile.dims.x, pairs.profile.dims.y)
    value = pa.float64() if dtype == "float64" else pa.float32()
    frame = pairs.frame_index()

    def vectors(a: FloatArray, d: int) -> Any:
        flat = pa.array(a.astype(dtype).reshape(-1), value)
        return pa.FixedSizeListArray.from_arrays(flat, d)

    return pa.table({
        "observation.state": vectors(pairs.x, dx),
        "action": vectors(pairs.y, dy),
        "timestamp": pa.array((frame / pairs.fps).astype(np.float32), pa.float32()),
        "frame_index": pa.array(frame, pa.int64()),
        "episode_index": pa.array(pairs.episode, pa.int64()),
        "index": pa.array(np.arange(n), pa.int64()),
        "task_index": pa.array(np.zeros(n, dtype=np.int64), pa.int64()),
        "roger.tick": pa.array(pairs.tick, pa.int64()),
        "roger.subtask": pa.array(pairs.label, pa.string()),
        "roger.source": pa.array(pairs.source, pa.string()),
    })


def _episodes(pairs: Pairs, task: str, dtype: str) -> Any:
    pa = require_pyarrow()
    starts = np.flatnonzero(np.diff(pairs.episode, prepend=-1))
    ends = np.append(starts[1:], len(pairs))
    cols: dict[str, Any] = {
        "episode_index": pa.array(range(len(starts)), pa.int64()),
        "tasks": pa.array([[task]] * len(starts), pa.list_(pa.string())),
        "length": pa.array(ends - starts, pa.int64()),
        "data/chunk_index": pa.array([0] * len(starts), pa.int64()),
        "data/file_index": pa.array([0] * len(starts), pa.int64()),
        "dataset_from_index": pa.array(starts, pa.int64()),
        "dataset_to_index": pa.array(ends, pa.int64()),
        "meta/episodes/chunk_index": pa.array([0] * len(starts), pa.int64()),
        "meta/episodes/file_index": pa.array([0] * len(starts), pa.int64()),
    }
    for key, values in (("observation.state", pairs.x), ("action", pairs.y)):
        per = [stats_of(values[a:b].astype(dtype)) for a, b in zip(starts, ends, strict=True)]
        for stat in ("min", "max", "mean", "std", "count"):
            cols[f"stats/{key}/{stat}"] = pa.array([p[stat] for p in per],
                                                   pa.list_(pa.float64()))
    return pa.table(cols)


def _info(pairs: Pairs, dtype: str) -> dict[str, Any]:
    p = pairs.profile
    features = {
        "observation.state": {"dtype": dtype, "shape": [p.dims.x], "names": list(p.x_names)},
        "action": {"dtype": dtype, "shape": [p.dims.y], "names": list(p.y_names)},
        **DEFAULT_FEATURES, **ROGER_FEATURES,
    }
    return {
        "codebase_version": CODEBASE_VERSION, "robot_type": p.name or pairs.robot,
        "total_episodes": pairs.episodes, "total_frames": len(pairs), "total_tasks": 1,
        "chunks_size": 1000, "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
        "fps": max(1, round(pairs.fps)), "splits": {"train": f"0:{pairs.episodes}"},
        "data_path": DATA_PATH, "video_path": None, "features": features,
    }


def write_lerobot(pairs: Pairs, root: str | Path, *, dtype: str = "float64") -> list[Path]:
    """Write ``pairs`` as a LeRobot v3 dataset under ``root`` (an existing, empty
    directory); return the files written."""
    import pyarrow.parquet as pq

    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    if not len(pairs):
        raise ValueError("no pairs to write")
    out = Path(root)
    task = pairs.task or pairs.profile.task or f"ROGER demonstration ({pairs.robot})"
    written: list[Path] = []

    def path(rel: str) -> Path:
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        written.append(p)
        return p

    frames = _frames(pairs, dtype)
    writer = pq.ParquetWriter(str(path(DATA_PATH.format(chunk_index=0, file_index=0))),
                              frames.schema, compression="snappy")
    try:  # one row group per episode, as LeRobot writes them
        starts = np.flatnonzero(np.diff(pairs.episode, prepend=-1))
        for a, b in zip(starts, [*starts[1:], len(pairs)], strict=True):
            writer.write_table(frames.slice(int(a), int(b - a)))
    finally:
        writer.close()
    pq.write_table(_episodes(pairs, task, dtype),
                   str(path(EPISODES_PATH.format(chunk_index=0, file_index=0))))
    pq.write_table(_tasks_table([task]), str(path("meta/tasks.parquet")))
    stats = {"observation.state": stats_of(pairs.x.astype(dtype), quantiles=True),
             "action": stats_of(pairs.y.astype(dtype), quantiles=True)}
    for rel, doc in (("meta/info.json", _info(pairs, dtype)), ("meta/stats.json", stats),
                     ("meta/roger.json", {"robot": pairs.robot, "fps": pairs.fps,
                                          "profile": pairs.profile.to_mapping(),
                                          **pairs.meta})):
        path(rel).write_text(json.dumps(doc, indent=4) + "\n", encoding="utf-8")
    return written


def _read_json(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path} is not a JSON object")
    return doc


def _names(names: Any) -> Any:
    """A feature's entry names: a list, or the one list of a map such as ``{"motors": [...]}``
    (how datasets converted from LeRobot's older versions name them)."""
    if isinstance(names, dict) and len(names) == 1:
        return next(iter(names.values()))
    return names


def _profile(info: dict[str, Any], roger: dict[str, Any], x_key: str, y_key: str,
             dx: int, dy: int) -> RobotProfile:
    from protocols.messages import Dims

    if isinstance(roger.get("profile"), dict):
        prof = RobotProfile.from_mapping(roger["profile"])
        if prof.dims == Dims(dx, dy):
            return prof
    names = [_names(info["features"][k].get("names")) for k in (x_key, y_key)]
    base = generic_profile(Dims(dx, dy), name=str(info.get("robot_type") or ""))
    if all(isinstance(n, list) and all(isinstance(s, str) for s in n) for n in names) and \
            [len(n) for n in names] == [dx, dy]:
        return RobotProfile(name=base.name, x_names=tuple(names[0]), y_names=tuple(names[1]))
    return base


def read_lerobot(root: str | Path, *, x_key: str = "observation.state",
                 y_key: str = "action") -> Pairs:
    """A LeRobot v3 dataset's frames as :class:`Pairs` (``x_key``/``y_key``: the features
    that are the perception and the action); ``ValueError`` naming what is missing."""
    import pyarrow.parquet as pq

    base = Path(root)
    info = _read_json(base / "meta" / "info.json")
    version = str(info.get("codebase_version", ""))
    if not version.startswith("v3"):
        raise ValueError(f"{base}: codebase_version {version!r}; this reads LeRobot v3 "
                         "datasets (convert older ones with LeRobot's "
                         "convert_dataset_v21_to_v30)")
    feats = info.get("features", {})
    for k in (x_key, y_key):
        if k not in feats:
            raise ValueError(f"{base}: no feature {k!r} in meta/info.json (features: "
                             f"{', '.join(sorted(feats))})")
    files = sorted((base / "data").glob("chunk-*/file-*.parquet"))
    if not files:
        raise ValueError(f"{base}: no data/chunk-*/file-*.parquet")
    tables = [pq.read_table(f) for f in files]
    cols = {name: np.concatenate([column_array(t, name) for t in tables])
            for name in tables[0].column_names}
    order = np.argsort(cols["index"], kind="stable") if "index" in cols else slice(None)
    x, y = cols[x_key][order].astype(np.float64), cols[y_key][order].astype(np.float64)
    x, y = x.reshape(len(x), -1), y.reshape(len(y), -1)
    roger = (_read_json(base / "meta" / "roger.json")
             if (base / "meta" / "roger.json").is_file() else {})
    episode = cols["episode_index"][order].astype(np.int64)
    renumber = {e: i for i, e in enumerate(dict.fromkeys(episode.tolist()))}
    n = len(x)

    def strings(name: str) -> list[str]:
        return [str(v) for v in cols[name][order]] if name in cols else [""] * n

    meta = {k: str(v) for k, v in roger.items()
            if k in ("learner_params", "seed", "model", "session_id", "source_log")}
    prof = _profile(info, roger, x_key, y_key, x.shape[1], y.shape[1])
    return Pairs(x=x, y=y,
                 tick=(cols["roger.tick"][order].astype(np.int64) if "roger.tick" in cols
                       else np.arange(n, dtype=np.int64)),
                 episode=np.array([renumber[e] for e in episode.tolist()], dtype=np.int64),
                 label=strings("roger.subtask"), source=strings("roger.source"),
                 profile=prof, fps=float(roger.get("fps") or info.get("fps") or 30),
                 robot=_robot_id(str(roger.get("robot") or prof.name or "robot")), meta=meta)


def _robot_id(name: str) -> str:
    """A valid robot id from a dataset's robot name (``[A-Za-z0-9_-]{1,64}``)."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", name)[:64] or "robot"

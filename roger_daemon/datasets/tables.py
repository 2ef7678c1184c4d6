"""Plain Parquet and HDF5 (robomimic's layout) datasets of training pairs, and their helpers.

* **Parquet** (``<name>.parquet``, one table, one row per pair): ``index``, ``episode_index``,
  ``frame_index``, ``timestamp``, ``tick``, ``subtask``, ``source``, then one float64 column
  per named entry, ``x.<perception name>`` and ``y.<action name>`` (``df["x.ball_x"]`` in
  pandas). The schema's metadata ``roger`` (JSON) holds the robot profile, fps and learner
  settings, so reading it back gives the same :class:`~roger_daemon.datasets.pairs.Pairs`.
* **HDF5** (``<name>.hdf5``, robomimic's layout): ``data/demo_<e>/obs/state`` (frames x d_x),
  ``data/demo_<e>/actions`` (frames x d_y), ``dones`` (1 on an episode's last frame),
  ``rewards`` (zeros: a demonstration has none, robomimic's loader asks for them), ROGER's
  ``ticks``, ``subtasks`` and ``sources``; ``demo_<e>.attrs["num_samples"]``;
  ``data.attrs["total"]``, ``data.attrs["env_args"]`` (JSON) and ``data.attrs["roger"]``
  (the same JSON as the Parquet file's). Needs ``h5py`` (``pip install 'roger[datasets]'``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Any

import numpy as np

from roger_daemon.datasets.pairs import FloatArray, Pairs
from roger_daemon.profiles import RobotProfile

__all__ = ["column_array", "read_hdf5", "read_parquet", "require_pyarrow", "stats_of",
           "write_hdf5", "write_parquet"]

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)


def require_pyarrow() -> Any:
    """The ``pyarrow`` module, or ``ImportError`` saying how to install it."""
    try:
        import pyarrow
    except ImportError:
        raise ImportError("dataset export and import need pyarrow: pip install "
                          "'roger[datasets]' (or pip install pyarrow)") from None
    return pyarrow


def _h5py() -> Any:
    try:
        import h5py
    except ImportError:
        raise ImportError("HDF5 datasets need h5py: pip install 'roger[datasets]' "
                          "(or pip install h5py)") from None
    return h5py


def stats_of(values: FloatArray, quantiles: bool = False) -> dict[str, list[float]]:
    """LeRobot's per-feature statistics of ``values`` (frames x entries)."""
    v = np.asarray(values, dtype=np.float64)
    out = {"min": v.min(0).tolist(), "max": v.max(0).tolist(), "mean": v.mean(0).tolist(),
           "std": v.std(0).tolist(), "count": [float(len(v))]}
    if quantiles:
        for q in QUANTILES:
            out[f"q{round(q * 100):02d}"] = np.quantile(v, q, axis=0).tolist()
    return out


def column_array(table: Any, name: str) -> Any:
    """A column as a numpy array (fixed-size lists as a 2-D float array)."""
    pa = require_pyarrow()
    col = table.column(name).combine_chunks()
    if pa.types.is_fixed_size_list(col.type) or pa.types.is_list(col.type):
        flat = col.flatten().to_numpy(zero_copy_only=False)
        return flat.reshape(len(col), -1)
    return col.to_numpy(zero_copy_only=False)


def _roger_json(pairs: Pairs) -> str:
    return json.dumps({"robot": pairs.robot, "fps": pairs.fps, "task": pairs.task,
                       "profile": pairs.profile.to_mapping(), **pairs.meta})


def _from_roger_json(text: str | bytes, what: str) -> tuple[dict[str, Any], RobotProfile]:
    try:
        doc = json.loads(text)
        return doc, RobotProfile.from_mapping(doc["profile"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{what}: its ROGER metadata is unreadable ({exc})") from None


def _pairs(doc: dict[str, Any], profile: RobotProfile, **arrays: Any) -> Pairs:
    meta = {k: str(doc[k]) for k in ("learner_params", "seed", "model", "session_id",
                                     "source_log") if doc.get(k)}
    return Pairs(profile=profile, fps=float(doc.get("fps") or profile.rate_hz),
                 robot=str(doc.get("robot") or profile.name or "robot"),
                 task=str(doc.get("task") or ""), meta=meta, **arrays)


def write_parquet(pairs: Pairs, path: str | Path | IO[bytes]) -> None:
    """Write the pairs as one Parquet table at ``path`` (or into an open binary file)."""
    pa = require_pyarrow()
    import pyarrow.parquet as pq

    frame = pairs.frame_index()
    cols: dict[str, Any] = {
        "index": pa.array(np.arange(len(pairs)), pa.int64()),
        "episode_index": pa.array(pairs.episode, pa.int64()),
        "frame_index": pa.array(frame, pa.int64()),
        "timestamp": pa.array(frame / pairs.fps, pa.float64()),
        "tick": pa.array(pairs.tick, pa.int64()),
        "subtask": pa.array(pairs.label, pa.string()),
        "source": pa.array(pairs.source, pa.string()),
    }
    for axis, names, values in (("x", pairs.profile.x_names, pairs.x),
                                ("y", pairs.profile.y_names, pairs.y)):
        for i, name in enumerate(names):
            cols[f"{axis}.{name}"] = pa.array(values[:, i], pa.float64())
    table = pa.table(cols).replace_schema_metadata({b"roger": _roger_json(pairs).encode()})
    pq.write_table(table, path if hasattr(path, "write") else str(path))


def read_parquet(path: str | Path) -> Pairs:
    """A Parquet file of :func:`write_parquet` as :class:`Pairs`."""
    require_pyarrow()
    import pyarrow.parquet as pq

    table = pq.read_table(str(path))
    meta = (table.schema.metadata or {}).get(b"roger")
    if meta is None:
        raise ValueError(f"{path}: no ROGER metadata; write it with roger log export "
                         "--format parquet")
    doc, profile = _from_roger_json(meta, str(path))
    try:
        x = np.column_stack([column_array(table, f"x.{n}") for n in profile.x_names])
        y = np.column_stack([column_array(table, f"y.{n}") for n in profile.y_names])
    except KeyError as exc:
        raise ValueError(f"{path}: a column is missing ({exc})") from None
    return _pairs(doc, profile, x=x.astype(np.float64), y=y.astype(np.float64),
                  tick=column_array(table, "tick").astype(np.int64),
                  episode=column_array(table, "episode_index").astype(np.int64),
                  label=[str(v) for v in column_array(table, "subtask")],
                  source=[str(v) for v in column_array(table, "source")])


def write_hdf5(pairs: Pairs, path: str | Path | IO[bytes]) -> None:
    """Write the pairs in robomimic's HDF5 layout at ``path`` (or into an open binary file,
    readable and seekable)."""
    h5py = _h5py()
    text = h5py.string_dtype()
    starts = np.flatnonzero(np.diff(pairs.episode, prepend=-1))
    with h5py.File(path if hasattr(path, "write") else str(path), "w") as f:
        data = f.create_group("data")
        for e, (a, b) in enumerate(zip(starts, [*starts[1:], len(pairs)], strict=True)):
            demo = data.create_group(f"demo_{e}")
            demo.create_dataset("obs/state", data=pairs.x[a:b])
            demo.create_dataset("actions", data=pairs.y[a:b])
            dones = np.zeros(b - a, dtype=np.int64)
            dones[-1] = 1
            demo.create_dataset("dones", data=dones)
            demo.create_dataset("rewards", data=np.zeros(b - a))
            demo.create_dataset("ticks", data=pairs.tick[a:b])
            demo.create_dataset("subtasks", data=pairs.label[a:b], dtype=text)
            demo.create_dataset("sources", data=pairs.source[a:b], dtype=text)
            demo.attrs["num_samples"] = int(b - a)
        data.attrs["total"] = len(pairs)
        data.attrs["env_args"] = json.dumps({"env_name": pairs.robot, "type": "roger",
                                             "env_kwargs": {}})
        data.attrs["roger"] = _roger_json(pairs)


def read_hdf5(path: str | Path) -> Pairs:
    """An HDF5 file of :func:`write_hdf5` as :class:`Pairs`."""
    h5py = _h5py()
    with h5py.File(str(path), "r") as f:
        if "data" not in f or "roger" not in f["data"].attrs:
            raise ValueError(f"{path}: no data group with ROGER metadata; write it with "
                             "roger log export --format hdf5")
        data = f["data"]
        doc, profile = _from_roger_json(data.attrs["roger"], str(path))
        demos = sorted((k for k in data if k.startswith("demo_")), key=lambda k: int(k[5:]))
        parts: dict[str, list[Any]] = {k: [] for k in ("x", "y", "tick", "episode", "label",
                                                        "source")}
        for e, name in enumerate(demos):
            demo = data[name]
            n = int(demo.attrs["num_samples"])
            parts["x"].append(demo["obs/state"][()])
            parts["y"].append(demo["actions"][()])
            parts["tick"].append(demo["ticks"][()])
            parts["episode"].append(np.full(n, e, dtype=np.int64))
            parts["label"] += [s.decode() if isinstance(s, bytes) else str(s)
                               for s in demo["subtasks"][()]]
            parts["source"] += [s.decode() if isinstance(s, bytes) else str(s)
                                for s in demo["sources"][()]]
    return _pairs(doc, profile, x=np.concatenate(parts["x"]).astype(np.float64),
                  y=np.concatenate(parts["y"]).astype(np.float64),
                  tick=np.concatenate(parts["tick"]).astype(np.int64),
                  episode=np.concatenate(parts["episode"]), label=parts["label"],
                  source=parts["source"])

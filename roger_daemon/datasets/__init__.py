"""Demonstrations in and out of ROGER: LeRobot v3, plain Parquet and HDF5 datasets.

``roger log export LOG --format lerobot|parquet|hdf5 --out DIR`` writes the pairs a session
learned (:func:`export_log`); ``roger log import DATASET --out DIR`` turns a dataset (one of
these, or any LeRobot v3 dataset) into a session log the daemon's tools learn from
(:func:`import_dataset`: ``roger replay`` rebuilds the model, ``--publish`` feeds a live
daemon). Export then import gives the same pairs, bit for bit (float64, the default).

* :mod:`.pairs`: :class:`Pairs` and :func:`pairs_from_log` (episodes, labels, sources, names);
* :mod:`.lerobot`: LeRobot's dataset v3.0 layout, with pyarrow only;
* :mod:`.tables`: one Parquet table; robomimic's HDF5 layout (h5py);
* :mod:`.session`: pairs into a version-2 session log.

The formats need ``pyarrow`` (and ``h5py`` for HDF5): ``pip install 'roger[datasets]'``.
``docs/datasets.md`` has the columns and conventions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from roger_daemon.datasets.pairs import Pairs, pairs_from_log

__all__ = ["FORMATS", "Pairs", "export_log", "import_dataset", "pairs_from_log",
           "read_dataset", "write_dataset"]

#: format -> the file it writes in the output directory ("" for a whole-directory format)
FORMATS = {"lerobot": "", "parquet": ".parquet", "hdf5": ".hdf5"}


def write_dataset(pairs: Pairs, fmt: str, out: str | Path, stem: str, *,
                  dtype: str = "float64") -> list[Path]:
    """Write ``pairs`` in ``fmt`` into the directory ``out``; return the files written."""
    from roger_daemon.datasets import lerobot, tables

    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    d = Path(out)
    if fmt == "lerobot":
        return lerobot.write_lerobot(pairs, d, dtype=dtype)
    target = d / f"{stem}{FORMATS[fmt]}"
    (tables.write_parquet if fmt == "parquet" else tables.write_hdf5)(pairs, target)
    return [target]


def export_log(log: str | Path, fmt: str, out: str | Path, *, robot: str | None = None,
               profile: Any = None, dtype: str = "float64") -> tuple[Pairs, list[Path]]:
    """The learned pairs of a session log, written in ``fmt`` into ``out``."""
    pairs = pairs_from_log(log, robot=robot, profile=profile)
    return pairs, write_dataset(pairs, fmt, out, Path(log).stem, dtype=dtype)


def read_dataset(path: str | Path, *, x_key: str = "observation.state",
                 y_key: str = "action") -> Pairs:
    """A dataset by its form: a LeRobot directory (``meta/info.json``), a ``.parquet`` or an
    ``.hdf5``/``.h5`` file; ``ValueError`` if it is none of them."""
    from roger_daemon.datasets import lerobot, tables

    p = Path(path)
    if p.is_dir():
        if not (p / "meta" / "info.json").is_file():
            raise ValueError(f"{p} is a directory without meta/info.json: not a LeRobot "
                             "dataset")
        return lerobot.read_lerobot(p, x_key=x_key, y_key=y_key)
    if not p.is_file():
        raise ValueError(f"{p}: no such file or directory")
    if p.suffix == ".parquet":
        return tables.read_parquet(p)
    if p.suffix in (".hdf5", ".h5"):
        return tables.read_hdf5(p)
    raise ValueError(f"{p}: expected a LeRobot dataset directory, a .parquet or an .hdf5 file")


def import_dataset(path: str | Path, out: str | Path, *, params: Any, seed: int = 0,
                   model: str = "roger", robot: str | None = None,
                   x_key: str = "observation.state", y_key: str = "action"
                   ) -> tuple[Pairs, Path]:
    """Read a dataset and write it as a session log in the directory ``out``."""
    from dataclasses import replace

    from roger_daemon.datasets.session import write_session

    pairs = read_dataset(path, x_key=x_key, y_key=y_key)
    if robot:
        pairs = replace(pairs, robot=robot)
    log = write_session(pairs, out, params=params, seed=seed, model=model,
                        source_name=Path(path).name)
    return pairs, log

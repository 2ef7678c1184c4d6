"""``roger log export --format lerobot|parquet|hdf5`` and ``roger log import``: the arguments.

Export: the learned pairs of a session log into ``--out DIR`` (a LeRobot dataset is the
directory itself; Parquet and HDF5 write ``DIR/<log name>.parquet|.hdf5``); without
``--out``, beside the log. A LeRobot directory that holds anything but an earlier export is
refused unless ``--force`` (:func:`roger_daemon.atomic.owned_output_dir`).

Import: a dataset into a new session log in ``--out DIR`` (default: the current directory),
learned with the learner settings the dataset records (a ROGER export), else those of a daemon
config's robot (``--config``), else ``--preset`` with the robot profile's scaling.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from roger_daemon.console import UsageError
from roger_daemon.recording.outputs import bad_input, existing_output, refuse_stdout

__all__ = ["configure_export", "configure_import", "run_export", "run_import"]

FORMAT_CHOICES = ("json", "lerobot", "parquet", "hdf5")


def configure_export(p: argparse.ArgumentParser) -> None:
    """Arguments of ``roger log export``."""
    p.add_argument("file", type=Path, metavar="FILE", help="an MCAP session log (msgpack)")
    p.add_argument("--format", choices=FORMAT_CHOICES, default="json",
                   help="json: the whole session as a json + jsonschema MCAP with named "
                        "fields (Foxglove opens it; default); lerobot: the learned pairs as a "
                        "LeRobot v3 dataset; parquet: one table; hdf5: robomimic's layout")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output directory (lerobot: the dataset's root; json, parquet, hdf5: "
                        "DIR/<FILE's name>.json.mcap|.parquet|.hdf5); default: beside FILE "
                        "(--out FILE.mcap, the old json form, is deprecated but still works)")
    p.add_argument("--robot", default=None, metavar="ID",
                   help="the robot whose pairs to export (default: the log's)")
    p.add_argument("--profile", default=None, metavar="NAME|PATH",
                   help="robot profile naming the fields (default: the one the log records, "
                        "else the shipped profile of its dimensions)")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64",
                   help="lerobot: the vectors' type (float64, default: import gives the same "
                        "pairs bit for bit; float32: LeRobot's usual)")
    p.add_argument("--json", action="store_true", help="report as JSON")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing output (lerobot: delete what the directory "
                        "holds)")


def configure_import(p: argparse.ArgumentParser) -> None:
    """Arguments of ``roger log import``."""
    p.add_argument("dataset", type=Path, metavar="DATASET",
                   help="a LeRobot v3 dataset directory, or a .parquet / .hdf5 file of "
                        "roger log export")
    p.add_argument("--out", type=Path, default=Path("."), metavar="DIR",
                   help="directory for the session log roger-<robot>-<start>.mcap "
                        "(default: the current directory)")
    p.add_argument("--robot", default=None, metavar="ID",
                   help="robot id of the session (default: the dataset's)")
    p.add_argument("--config", type=Path, default=None, metavar="TOML",
                   help="learn with this daemon config's settings for the robot (default: "
                        "the settings the dataset records, else --preset)")
    p.add_argument("--preset", default="default", metavar="NAME",
                   help="learner preset for a dataset that records no settings (default: "
                        "default), with the robot profile's scaling")
    p.add_argument("--seed", type=int, default=None, metavar="N",
                   help="model seed (default: the dataset's, else 0)")
    p.add_argument("--x-feature", default="observation.state", metavar="KEY",
                   help="LeRobot feature that is the perception (default observation.state)")
    p.add_argument("--y-feature", default="action", metavar="KEY",
                   help="LeRobot feature that is the action (default action)")
    p.add_argument("--json", action="store_true", help="report as JSON")


def _need(module: str) -> None:
    try:
        __import__(module)
    except ImportError:
        raise UsageError(f"this format needs {module}: pip install 'roger[datasets]' (or "
                         f"pip install {module})") from None


def _profile(spec: str | None) -> Any:
    if spec is None:
        return None
    from roger_daemon.profiles import ProfileError, load_profile

    try:
        return load_profile(spec)
    except ProfileError as exc:
        raise UsageError(f"--profile: {exc}") from None


def run_export(args: argparse.Namespace) -> int:
    """``roger log export --format lerobot|parquet|hdf5``."""
    from roger_daemon.atomic import OutputDirError, owned_output_dir
    from roger_daemon.datasets import FORMATS, pairs_from_log, write_dataset

    refuse_stdout("log export", args.out)
    _need("pyarrow")
    if args.format == "hdf5":
        _need("h5py")
    if bad_input("export", args.file):
        return 1
    profile = _profile(args.profile)
    stem = args.file.stem
    try:
        pairs = pairs_from_log(args.file, robot=args.robot, profile=profile)
    except ValueError as exc:
        print(f"roger log export: {exc}", file=sys.stderr)
        return 1
    try:
        if args.format == "lerobot":
            out = args.out or args.file.with_name(f"{stem}.lerobot")
            with owned_output_dir(out, "log export", force=args.force) as d:
                files = write_dataset(pairs, "lerobot", d, stem, dtype=args.dtype)
        else:
            out = args.out or args.file.parent
            if out.exists() and not out.is_dir():
                raise UsageError(f"--out must be a directory, got the file {out}")
            target = out / f"{stem}{FORMATS[args.format]}"
            if existing_output("export", target, args.force):
                return 2
            out.mkdir(parents=True, exist_ok=True)
            files = _atomically(pairs, args.format, target)
    except OutputDirError as exc:
        print(f"roger log export: {exc}", file=sys.stderr)
        return 2
    _report(args.json, {"output": str(out), "format": args.format, "files": list(map(str, files)),
                        "pairs": len(pairs), "episodes": pairs.episodes, "fps": pairs.fps,
                        "robot": pairs.robot, "profile": pairs.profile.name},
            f"wrote {len(pairs)} pairs in {pairs.episodes} episode(s) of robot {pairs.robot} as "
            f"{args.format}: {', '.join(map(str, files))}")
    return 0


def _atomically(pairs: Any, fmt: str, target: Path) -> list[Path]:
    """Write one dataset file complete or not at all (:func:`roger_daemon.atomic.atomic_write`)."""
    from roger_daemon.atomic import atomic_write
    from roger_daemon.datasets import tables

    with atomic_write(target) as f:
        (tables.write_parquet if fmt == "parquet" else tables.write_hdf5)(pairs, f)
    return [target]


def _report(as_json: bool, doc: dict[str, Any], text: str) -> None:
    print(json.dumps(doc, indent=2, sort_keys=True) if as_json else text)


def _import_params(args: argparse.Namespace, pairs: Any) -> tuple[Any, int, str]:
    """``(params, seed, model)`` of an import (module docstring)."""
    from roger_daemon.learner import ParameterError, RogerParams

    seed = int(pairs.meta.get("seed") or 0) if args.seed is None else args.seed
    if args.config is not None:
        from roger_daemon.config import ConfigError, load_config

        try:
            cfg = load_config(args.config)
        except ConfigError as exc:
            raise UsageError(f"--config: {exc}") from None
        robot = next((r for r in cfg.robots if r.id == pairs.robot), None)
        if robot is None and len(cfg.robots) == 1:
            robot = cfg.robots[0]
        if robot is None:
            raise UsageError(f"--config {args.config} has no robot {pairs.robot!r} "
                             f"(robots: {', '.join(r.id for r in cfg.robots)}); pass --robot")
        return robot.params, robot.seed if args.seed is None else seed, robot.model
    try:
        if pairs.meta.get("learner_params"):
            params = RogerParams.from_mapping(json.loads(pairs.meta["learner_params"]))
        else:
            params = pairs.profile.params(args.preset)
    except (ParameterError, ValueError) as exc:
        raise UsageError(f"learner settings for the import: {exc}") from None
    return params, seed, pairs.meta.get("model") or "roger"


def run_import(args: argparse.Namespace) -> int:
    """``roger log import``."""
    from dataclasses import replace

    from roger_daemon.datasets import read_dataset
    from roger_daemon.datasets.session import write_session
    from roger_daemon.profiles import ProfileError

    refuse_stdout("log import", args.out)
    _need("pyarrow")
    if args.dataset.suffix in (".hdf5", ".h5"):
        _need("h5py")
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"--out must be a directory, got the file {args.out}")
    try:
        pairs = read_dataset(args.dataset, x_key=args.x_feature, y_key=args.y_feature)
    except (ValueError, ProfileError, OSError) as exc:
        print(f"roger log import: {exc}", file=sys.stderr)
        return 1
    if args.robot:
        from protocols import keys
        from protocols.errors import ProtocolError

        try:
            keys.validate_robot_id(args.robot)
        except ProtocolError as exc:
            raise UsageError(f"--robot: {exc}") from None
        pairs = replace(pairs, robot=args.robot)
    params, seed, model = _import_params(args, pairs)
    log = write_session(pairs, args.out, params=params, seed=seed, model=model,
                        source_name=args.dataset.name)
    _report(args.json, {"output": str(log), "pairs": len(pairs), "episodes": pairs.episodes,
                        "robot": pairs.robot, "seed": seed, "model": model},
            f"wrote {log}: {len(pairs)} pairs in {pairs.episodes} episode(s) of robot "
            f"{pairs.robot} (roger replay {log} --save-checkpoint DIR builds its model)")
    return 0

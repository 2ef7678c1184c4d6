"""``roger daemon``: the learner service over Zenoh (thin entry point).

Start-up order: signal handlers, configuration (a bad one exits 2 naming the key), models
(resumed from the newest valid checkpoint unless ``--fresh``), recorders, the Zenoh session
(opened last, never forked after), then READY=1 and the loop. SIGTERM/SIGINT end the loop;
shutdown drains, checkpoints and closes within a few seconds, exit status 0.
"""

from __future__ import annotations

import os

# One thread computes (the loop owns the model); multithreaded BLAS on a small machine only
# fights Zenoh's threads and the other processes for cores: measured on 2 cores, a busy second
# core doubled learn_one's median and produced 60-80 ms spikes. Must precede numpy's import;
# an explicit setting in the environment wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import signal  # noqa: E402
from pathlib import Path  # noqa: E402
from types import FrameType  # noqa: E402
from typing import Any  # noqa: E402

from protocols.messages import MAX_PAYLOAD_BYTES, SCHEMA_VERSION, Dims  # noqa: E402
from roger_daemon.checkpoint import Checkpoint, CheckpointError, load_newest  # noqa: E402
from roger_daemon.config import ConfigError, DaemonConfig, RobotConfig, load_config  # noqa: E402
from roger_daemon.robot import RobotRuntime  # noqa: E402
from roger_daemon.sdnotify import Notifier  # noqa: E402
from roger_daemon.service import Recorder, Service  # noqa: E402

__all__ = ["build_robot", "configure", "run"]

log = logging.getLogger(__name__)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger daemon``."""
    parser.add_argument("--config", type=Path, default=None,
                        help="TOML config (default: built-in defaults, robot 'aibo')")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="SECTION.KEY=VALUE",
                        help="override one config value (TOML syntax), e.g. daemon.clock=lockstep")
    parser.add_argument("--fresh", action="store_true",
                        help="ignore existing checkpoints and start with fresh models")
    parser.add_argument("--check", action="store_true",
                        help="validate the config, print it as JSON and exit")


def make_model(robot: RobotConfig) -> Any:
    """A fresh model for ``robot`` (the paper's ROGER or the unimap baseline)."""
    from roger_daemon.learner import Roger, UnimapGP

    cls = UnimapGP if robot.model == "unimap" else Roger
    return cls(d_x=robot.x_dim, d_y=robot.y_dim, params=robot.params, seed=robot.seed)


def _model_meta(robot: RobotConfig) -> dict[str, Any]:
    return {"model": robot.model, "seed": robot.seed, "params": robot.params.to_mapping()}


def build_robot(cfg: DaemonConfig, robot: RobotConfig, *, fresh: bool) -> tuple[RobotRuntime, str]:
    """The runtime of one robot, resumed from its newest valid checkpoint unless ``fresh``."""
    from roger_daemon.learner import load_model

    dims = Dims(robot.x_dim, robot.y_dim)
    loaded: dict[str, Any] = {}

    def accept(ck: Checkpoint) -> None:
        if (ck.meta.get("x_dim"), ck.meta.get("y_dim")) != (robot.x_dim, robot.y_dim):
            raise CheckpointError(
                f"dimensions {ck.meta.get('x_dim')}/{ck.meta.get('y_dim')} do not match the "
                f"config's {robot.x_dim}/{robot.y_dim}"
            )
        try:
            loaded["model"] = load_model(ck.model)
        except Exception as exc:  # the learner rejects a state it cannot continue from
            raise CheckpointError(f"the learner cannot load its model state ({exc})") from None
        if int(loaded["model"].n_learned) != len(ck.daemon.get("label_codes", ())):
            raise CheckpointError("model and label counts disagree")

    rt = RobotRuntime(robot.id, dims, None, lambda: make_model(robot), mode=cfg.mode,
                      queue_size=cfg.queue_size, pair_window=cfg.pair_window)
    ckpt = None if fresh else load_newest(cfg.checkpoint.dir, robot.id, accept)
    if ckpt is None:
        rt.model = make_model(robot)
        return rt, ""
    rt.model = loaded["model"]
    rt.restore(ckpt.daemon, ckpt.meta.get("counters", {}))
    saved = ckpt.meta.get("params")
    if saved is not None and saved != robot.params.to_mapping():
        log.warning("%s: the checkpoint's learner parameters differ from the config's; "
                    "continuing with the checkpoint's (use --fresh to start over with the "
                    "config's)", robot.id)
    log.info("%s: resumed from %s (%d updates, %d queued pairs, model %s)", robot.id, ckpt.path,
             rt.updates, len(rt.queue), str(ckpt.meta.get("model_digest", ""))[:12])
    return rt, str(ckpt.path)


def _recorders(
    cfg: DaemonConfig, robots: dict[str, RobotRuntime], resumed: dict[str, str]
) -> dict[str, Recorder]:
    """One ``SessionRecorder`` per robot, or none (with a warning) if recording is missing."""
    if not cfg.recording.enabled:
        return {}
    try:
        from roger_daemon.recording import SessionRecorder, session_metadata
    except ImportError as exc:
        log.warning("recording is enabled but roger_daemon.recording is not available (%s); "
                    "running WITHOUT recording", exc)
        return {}
    config_text = ""
    if cfg.source is not None:
        try:
            config_text = cfg.source.read_text(encoding="utf-8")
        except OSError:
            config_text = ""
    out: dict[str, Recorder] = {}
    for robot in cfg.robots:
        rt = robots[robot.id]
        meta = session_metadata(
            robot=robot.id, config_text=config_text, learner_params=robot.params,
            dims=rt.dims, seed=robot.seed, model=robot.model, mode=rt.mode,
            start_updates=rt.updates, checkpoint=resumed.get(robot.id, ""),
            pair_window=cfg.pair_window, queue_size=cfg.queue_size,
            extra={"daemon": cfg.id, "clock": cfg.clock, "rate_hz": repr(cfg.rate_hz),
                   "schema_version": str(SCHEMA_VERSION),
                   # pairs saved unlearned in the checkpoint: learned first, before any pair
                   # of this session (they are in the checkpoint's daemon.queue_* arrays)
                   "restored_queued_pairs": str(len(rt.queue))},
        )
        rec = SessionRecorder(cfg.recording.dir, robot=robot.id, metadata=meta)
        log.info("%s: recording to %s", robot.id, rec.path)
        out[robot.id] = rec
    return out


def _describe(cfg: DaemonConfig) -> dict[str, Any]:
    return {
        "id": cfg.id, "clock": cfg.clock, "rate_hz": cfg.rate_hz, "status_hz": cfg.status_hz,
        "mode": cfg.mode, "queue_size": cfg.queue_size, "pair_window": cfg.pair_window,
        "seed": cfg.seed, "count_unserved": cfg.count_unserved,
        "robots": [{"id": r.id, "x_dim": r.x_dim, "y_dim": r.y_dim, "model": r.model,
                    "seed": r.seed, "learner": r.params.to_mapping()} for r in cfg.robots],
        "zenoh": {k: (str(v) if isinstance(v, Path) else v)
                  for k, v in vars(cfg.zenoh).items()},
        "checkpoint": {k: (str(v) if isinstance(v, Path) else v)
                       for k, v in vars(cfg.checkpoint).items()},
        "recording": {"enabled": cfg.recording.enabled, "dir": str(cfg.recording.dir)},
    }


def run(args: argparse.Namespace) -> int:
    """Run the daemon until SIGTERM/SIGINT; 0 on a clean stop, 2 on a config error."""
    stop: list[Service] = []
    requested = {"early": False}

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s", signal.Signals(signum).name)
        requested["early"] = True
        for s in stop:
            s.request_stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    try:
        cfg = load_config(args.config, args.overrides)
    except ConfigError as exc:
        log.error("%s", exc)
        return 2
    if args.check:
        print(json.dumps(_describe(cfg), indent=2))
        return 0
    if cfg.log_dir is not None:
        cfg.log_dir.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(cfg.log_dir / f"roger-daemon-{cfg.id}.log")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        logging.getLogger().addHandler(handler)

    notifier = Notifier.from_env()
    robots: dict[str, RobotRuntime] = {}
    resumed: dict[str, str] = {}
    for robot in cfg.robots:
        robots[robot.id], resumed[robot.id] = build_robot(cfg, robot, fresh=args.fresh)
    recorders = _recorders(cfg, robots, resumed)

    from roger_daemon.transport import ZenohTransport

    try:
        transport = ZenohTransport(cfg.zenoh, max_payload_bytes=MAX_PAYLOAD_BYTES)
    except Exception as exc:
        log.error("cannot open the Zenoh session (%s); check [zenoh] in the config", exc)
        for rec in recorders.values():
            rec.close()
        return 1
    by_id = {r.id: r for r in cfg.robots}
    service = Service(
        cfg, transport, robots, notifier=notifier, recorders=recorders, resumed=resumed,
        checkpoint_meta=lambda rt: _model_meta(by_id[rt.robot]),
    )
    stop.append(service)
    try:
        service.start()
    except Exception:
        transport.close()
        raise
    if requested["early"]:
        service.request_stop()
    try:
        service.run()
    except Exception:
        log.exception("the service loop failed")
        return 1
    finally:
        notifier.close()
    if not service.final_checkpoints_ok:
        log.error("the final checkpoint failed (see above): exit status 1")
        return 1
    return 0

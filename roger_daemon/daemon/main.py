"""``roger daemon``: the learner service over Zenoh (thin entry point).

Start-up order: signal handlers, configuration (a bad one exits 2 naming the key), models
(resumed from the newest valid checkpoint unless ``--fresh``), start-up self-recovery from the
session logs when recording is on and not ``--fresh`` (:mod:`roger_daemon.daemon.resume`:
footer-less logs recovered, the pairs logged after the checkpoint re-learned, a
``recovered`` checkpoint written), recorders, the Zenoh session (opened last, never forked
after), then READY=1 and the loop. SIGTERM/SIGINT end the loop; shutdown drains, checkpoints
and closes within a few seconds, exit status 0.
"""

from __future__ import annotations

# One BLAS thread computes (the loop owns the model): pinned for every `roger` command by
# roger_daemon.cli (roger_daemon/blas.py). Multithreaded BLAS on a small machine also fights
# Zenoh's threads for cores: measured on 2 cores, a busy second core doubled learn_one's
# median and produced 60-80 ms spikes.
import argparse
import json
import logging
import signal
from pathlib import Path
from types import FrameType
from typing import Any

from protocols.messages import MAX_PAYLOAD_BYTES, SCHEMA_VERSION
from roger_daemon.config import ConfigError, DaemonConfig, load_config
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.daemon.gc_policy import hold_collections
from roger_daemon.daemon.learner_host import InlineLearners, Learners
from roger_daemon.daemon.resume import (
    Resumed,
    build_robot,
    load_robot,
    make_model,
    model_meta,
    recover_from_logs,
    start_robots,
)
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.sdnotify import Notifier
from roger_daemon.daemon.service import Recorder, Service
from roger_daemon.daemon.wal import DISK_FULL_ERRNOS

__all__ = [
    "Resumed",
    "build_robot",
    "configure",
    "load_robot",
    "make_model",
    "model_meta",
    "open_recorders",
    "recover_from_logs",
    "run",
    "start_robots",
]

log = logging.getLogger(__name__)

#: ``systemctl status`` while the models load (``Notifier.starting``)
#: exit status on a full disk (``EX_TEMPFAIL`` of sysexits.h: start again once there is
#: space; docs/durability.md, *Disk full*)
EXIT_DISK_FULL = 75
STARTING = ("starting: loading the models (the first start after an install compiles the "
            "learner's kernels, about a minute)")


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


def open_recorders(
    cfg: DaemonConfig, robots: dict[str, RobotRuntime], resumed: dict[str, Resumed],
    recorder_options: dict[str, Any] | None = None,
) -> dict[str, Recorder]:
    """One ``SessionRecorder`` per robot, or none (with a warning) if recording is missing.

    ``recorder_options``: more ``SessionRecorder`` settings (rotation, start time; tests).
    """
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
    for i, robot in enumerate(cfg.robots):
        rt = robots[robot.id]
        where = resumed.get(robot.id, Resumed())
        meta = session_metadata(
            robot=robot.id, config_text=config_text, learner_params=robot.params,
            dims=rt.dims, seed=robot.seed, model=robot.model, mode=rt.mode,
            start_updates=rt.updates, checkpoint=where.checkpoint,
            pair_window=cfg.pair_window, queue_size=cfg.queue_size,
            # pairs saved unlearned in the checkpoint: learned first, before any pair of this
            # session (they are in the checkpoint's daemon.queue_* arrays)
            restored_queued_pairs=len(rt.queue),
            resumed_session=where.session or "", resumed_segment=where.segment,
            decisions=True,  # the service attaches each robot's DecisionLog
            start_model_digest=array_digest(dict(rt.model.state_dict())),
            extra={"daemon": cfg.id, "clock": cfg.clock, "rate_hz": repr(cfg.rate_hz),
                   # the robot's profile (names, ranges): exported datasets and logs name fields
                   **({"robot_profile": json.dumps(robot.robot_profile.to_mapping())}
                      if robot.robot_profile is not None else {}),
                   "schema_version": str(SCHEMA_VERSION),
                   "recovered_pairs": str(where.recovered_pairs),
                   "recovered_from": ",".join(where.recovered_from)},
        )
        # robot i of n flushes (i + 1)/n of a flush interval after the others: one chunk
        # compression per loop cycle, not n (docs/fleet.md, Status after the answers)
        options = {"flush_phase": (i + 1) / len(cfg.robots), **(recorder_options or {})}
        rec = SessionRecorder(cfg.recording.dir, robot=robot.id, metadata=meta, **options)
        log.info("%s: recording to %s", robot.id, rec.path)
        out[robot.id] = rec
    return out


def _start_learners(cfg: DaemonConfig, robots: dict[str, RobotRuntime]) -> Learners:
    """Where the models live: ``[daemon] workers`` = ``"process"`` (or ``"auto"`` with several
    robots) hands them to ``worker_processes`` worker processes, at ``worker_nice``; else the
    loop's own thread."""
    if cfg.learner_workers != "process":
        return InlineLearners(robots)
    from roger_daemon.daemon.learners import ProcessLearners

    return ProcessLearners(robots, {r.id: r for r in cfg.robots},
                           processes=cfg.worker_processes, nice=cfg.worker_nice)


def _describe(cfg: DaemonConfig) -> dict[str, Any]:
    return {
        "id": cfg.id, "clock": cfg.clock, "rate_hz": cfg.rate_hz, "status_hz": cfg.status_hz,
        "mode": cfg.mode, "queue_size": cfg.queue_size, "pair_window": cfg.pair_window,
        "seed": cfg.seed, "count_unserved": cfg.count_unserved,
        "workers": cfg.workers, "learner_workers": cfg.learner_workers,
        "worker_nice": cfg.worker_nice, "worker_processes": cfg.worker_processes,
        "robots": [{"id": r.id, "x_dim": r.x_dim, "y_dim": r.y_dim, "model": r.model,
                    "seed": r.seed, "profile": r.profile,
                    "learner": r.params.to_mapping()} for r in cfg.robots],
        "zenoh": {k: (str(v) if isinstance(v, Path) else v)
                  for k, v in vars(cfg.zenoh).items()},
        "checkpoint": {k: (str(v) if isinstance(v, Path) else v)
                       for k, v in vars(cfg.checkpoint).items()},
        "recording": {k: (str(v) if isinstance(v, Path) else v)
                      for k, v in vars(cfg.recording).items()},
    }


def _disk_full(cfg: DaemonConfig, exc: OSError, what: str) -> int:
    """The one line a full disk ends the daemon with (no traceback); its exit status."""
    where = exc.filename or (f"checkpoints and write-ahead log in {cfg.checkpoint.dir}" +
                             (f", recordings in {cfg.recording.dir}"
                              if cfg.recording.enabled else ""))
    log.error("%s: the disk is full (%s; %s). Free space there and start the daemon again "
              "(exit status %d; nothing acknowledged is lost: docs/durability.md, Disk full)",
              what, exc.strerror or exc, where, EXIT_DISK_FULL)
    return EXIT_DISK_FULL


def _serve(cfg: DaemonConfig, service: Service, notifier: Notifier) -> int:
    """Run the loop until it stops; the exit status (a full disk: :data:`EXIT_DISK_FULL`)."""
    try:
        service.run()
    except OSError as exc:
        if exc.errno not in DISK_FULL_ERRNOS:
            log.exception("the service loop failed")
            return 1
        return _disk_full(cfg, exc, "stopped")
    except Exception:
        log.exception("the service loop failed")
        return 1
    finally:
        notifier.close()
    if not service.final_checkpoints_ok:
        if any(st.error.startswith("the disk is full")
               for st in service.checkpoints.state.values()):
            log.error("the final checkpoint failed: the disk is full at %s; the write-ahead "
                      "log holds every pair learned (exit status %d)", cfg.checkpoint.dir,
                      EXIT_DISK_FULL)
            return EXIT_DISK_FULL
        log.error("the final checkpoint failed (see above): exit status 1")
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    """Run the daemon until SIGTERM/SIGINT; 0 on a clean stop, 2 on a config error,
    :data:`EXIT_DISK_FULL` on a disk too full to start or to go on."""
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

    from roger_daemon.daemon.memory import limit_heap_growth

    limit_heap_growth()
    notifier = Notifier.from_env()
    # Finite but possibly long under systemd's start timeout: the first start after an install
    # or upgrade compiles the learner's kernels (~1 min), recovery re-learns logged pairs.
    try:
        with notifier.starting(STARTING):
            robots, where = start_robots(cfg, fresh=args.fresh, notifier=notifier)
            resumed = {r: w.checkpoint for r, w in where.items()}
            recorders = open_recorders(cfg, robots, where)
            learners = _start_learners(cfg, robots)  # before Zenoh opens: never fork after
    except OSError as exc:
        if exc.errno not in DISK_FULL_ERRNOS:
            raise
        return _disk_full(cfg, exc, "cannot start")

    from roger_daemon.transport import ZenohTransport

    try:
        transport = ZenohTransport(cfg.zenoh, max_payload_bytes=MAX_PAYLOAD_BYTES)
    except Exception as exc:
        log.error("cannot open the Zenoh session (%s); check [zenoh] in the config", exc)
        for rec in recorders.values():
            rec.close()
        learners.close()
        return 1
    service = Service(cfg, transport, robots, notifier=notifier, recorders=recorders,
                      resumed=resumed, learners=learners)
    stop.append(service)
    try:
        service.start()
    except Exception:
        transport.close()
        learners.close()
        raise
    if requested["early"]:
        service.request_stop()
    # started: collections at the loop's quiet moments from now on (daemon/gc_policy.py)
    service.gc_thresholds = hold_collections()
    return _serve(cfg, service, notifier)

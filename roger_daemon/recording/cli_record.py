"""``roger record``: record Zenoh traffic to MCAP, standalone (like ``ros2 bag record``).

One loop owns everything: a FIFO channel subscriber (lossless while drained, and it is drained
completely every cycle), the :class:`~roger_daemon.recording.SessionRecorder`, and the stop flag
set by SIGINT/SIGTERM. Zenoh is never called from a callback. On stop the subscriber is drained
once more, the session closed, and the file finished (summary and index).
"""

from __future__ import annotations

import argparse
import logging
import re
import signal
import sys
import time
from pathlib import Path
from types import FrameType

from protocols import keys as keyexpr
from roger_daemon.recording.metadata import session_metadata
from roger_daemon.recording.writer import SessionRecorder, header_fields

__all__ = ["configure", "run"]

log = logging.getLogger("roger.record")

_ROBOT_KEY = re.compile(r"^roger/([A-Za-z0-9_\-]{1,64})/")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger record``."""
    from roger_daemon.recording import zenoh_net

    parser.add_argument(
        "--key", default=keyexpr.everything(), help="key expression to record (default roger/**)"
    )
    parser.add_argument("--out", required=True, type=Path, metavar="DIR",
                        help="directory for the MCAP files")
    parser.add_argument(
        "--robot",
        help="robot id for the file name (default: from --key roger/<robot>/..., else 'all')",
    )
    zenoh_net.add_arguments(parser)
    parser.add_argument("--flush-interval", type=float, default=1.0, metavar="S",
                        help="close the open chunk at least this often (default 1 s)")
    parser.add_argument("--rotate-mb", type=float, default=256.0, help="new part after this size")
    parser.add_argument("--rotate-every", "--rotate-s", dest="rotate_s", type=float,
                        default=3600.0, metavar="S",
                        help="new part after this many seconds (default 3600, 0: never; "
                             "--rotate-s: the deprecated spelling)")
    parser.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                        help="MCAP chunk compression (default zstd)")
    parser.add_argument("--queue", type=int, default=4096, help="subscriber FIFO capacity")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: until SIGINT/SIGTERM)")


def run(args: argparse.Namespace) -> int:
    """Record until SIGINT/SIGTERM (or ``--duration``); 0, or 130 after Ctrl-C."""
    import zenoh

    from roger_daemon.recording import zenoh_net
    from roger_daemon.zenoh_session import open_session, settings_from_args

    if args.out.exists() and not args.out.is_dir():
        print(f"roger record: --out {args.out} exists and is not a directory; expected a "
              "directory for the MCAP files", file=sys.stderr)
        return 2
    robot = args.robot
    if robot is None:
        m = _ROBOT_KEY.match(args.key)
        robot = m.group(1) if m and "*" not in m.group(1) else "all"
    keyexpr.validate_robot_id(robot)
    stop = {"flag": False, "signum": 0}

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop["flag"], stop["signum"] = True, signum

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    meta = session_metadata(
        robot=robot, created_by="roger record", mode="learn+predict",
        extra={"record_key": args.key},
    )
    session = open_session(settings_from_args(args))
    if not zenoh_net.reached(session, args, "roger record"):
        session.close()
        return 1
    rec = SessionRecorder(
        args.out,
        robot=robot,
        metadata=meta,
        flush_interval_s=args.flush_interval,
        rotate_bytes=int(args.rotate_mb * 1024 * 1024) if args.rotate_mb > 0 else None,
        rotate_s=args.rotate_s if args.rotate_s > 0 else None,
        compression=args.compression,
    )
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        with session:
            sub = session.declare_subscriber(args.key, zenoh.handlers.FifoChannel(args.queue))
            # Machine-readable line for scripts and tests: the file and that we are subscribed.
            print(f"recording {args.key} -> {rec.path}", flush=True)
            log.info("recording %s to %s", args.key, rec.path)
            while not stop["flag"]:
                got = _drain(sub, rec)
                rec.poll(time.monotonic_ns())
                if deadline is not None and time.monotonic() >= deadline:
                    break
                if got == 0:
                    time.sleep(0.002)
            for _ in range(10):  # what arrived before the stop; bounded under live traffic
                if not _drain(sub, rec):
                    break
            sub.undeclare()
    finally:
        rec.close()
        for s, h in old.items():
            signal.signal(s, h)
    st = rec.stats
    if st.messages == 0:
        log.warning("recorded no message on %s", args.key)
    print(f"recorded {st.messages} messages in {st.parts} file(s): "
          + ", ".join(str(p) for p in rec.paths), file=sys.stderr, flush=True)
    # Ctrl-C: 130, as every command interrupted in a terminal (docs/cli.md, exit statuses);
    # SIGTERM (a supervisor's stop): 0 after the clean close
    return 130 if stop["signum"] == signal.SIGINT else 0


def _drain(sub: object, rec: SessionRecorder, limit: int = 2000) -> int:
    """Write what is queued (at most ``limit``, so that ``poll`` runs between batches)."""
    n = 0
    while n < limit:
        sample = sub.try_recv()  # type: ignore[attr-defined]
        if sample is None:
            return n
        now = time.time_ns()
        payload = sample.payload.to_bytes()
        hf = header_fields(payload)
        if hf is not None:
            tick, stamp = hf
        else:
            ts = sample.timestamp
            tick, stamp = 0, (ts.get_time_as_ntp64().as_nanos() if ts is not None else now)
        rec.write(str(sample.key_expr), payload, log_time_ns=now, publish_time_ns=stamp,
                  sequence=tick)
        n += 1
    return n

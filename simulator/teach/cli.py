"""``roger teach``: demonstrate, watch and correct the robot live from a web page.

Starts ``roger daemon`` (learning live, recording the session), the simulator and the page's
server, and prints the page's address (``--http``, loopback by default). Ctrl-C (or SIGTERM)
stops everything it started and exits 130 (143). Each run writes a new ``OUT/session-N``:
``daemon.log``, ``recordings/`` (the session's MCAP log: every pair with its source),
``checkpoints/``, ``takes/`` (recordings started from the page) and ``summary.json``; nothing
already in ``OUT`` is touched. docs/teach.md is the user's guide.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
from pathlib import Path
from typing import Any

from roger_daemon.tools.common import seconds

__all__ = ["address", "configure", "config_for_page", "run"]

DEFAULT_HTTP = "127.0.0.1:8770"


def address(text: str) -> tuple[str, int]:
    """argparse type: ``HOST:PORT`` (port 0: any free one)."""
    host, sep, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, e.g. {DEFAULT_HTTP}, got {text!r}")
    return host, port


def _location(text: str) -> int:
    from simulator.episodes import START_LOCATIONS

    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value < len(START_LOCATIONS):
        raise argparse.ArgumentTypeError(
            f"expected a start location 0-{len(START_LOCATIONS) - 1}, got {text!r}")
    return value


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger teach``."""
    from simulator.teach.channel import MODES

    parser.add_argument("--http", type=address, default=address(DEFAULT_HTTP),
                        metavar="HOST:PORT",
                        help=f"where the page is served (default {DEFAULT_HTTP}; port 0: a "
                             "free one). The page has no login: keep it on loopback")
    parser.add_argument("--out", type=Path, default=Path("runs/teach"), metavar="DIR",
                        help="each run writes a new DIR/session-N (default runs/teach)")
    parser.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime",
                        help="realtime (default: 30 Hz, for a person) or lockstep (each tick "
                             "waits for the daemon and, when it drives, the teacher: the "
                             "scripted teacher)")
    parser.add_argument("--vision", choices=("rendered", "fast"), default="rendered",
                        help="the simulator's vision (default rendered: its camera image is "
                             "the page's)")
    parser.add_argument("--mode", choices=MODES, default="demonstrate",
                        help="the first mode (default demonstrate)")
    parser.add_argument("--location", type=_location, default=0,
                        help="the first episode's start location 0-12 (default 0)")
    parser.add_argument("--episode-duration", dest="time_limit", type=seconds, default=60.0,
                        metavar="S", help="simulated seconds per episode (default 60)")
    parser.add_argument("--seed", type=int, default=0, help="the simulator's and learner's seed")


def config_for_page(loop_settings: Any, kind: str) -> dict[str, Any]:
    """What the page gets on connect: key map, names, ranges, field, locations, clock."""
    from protocols.aibo import ACTION_NAMES, ACTION_RANGES, PERCEPTION_NAMES
    from simulator.config import FieldConfig
    from simulator.episodes import START_LOCATIONS
    from simulator.teach.channel import HEAD_RATE, KEYMAP, MODES, TURN_RATE

    f = FieldConfig()
    return {
        "keymap": [{"codes": list(codes), "does": does, "entry": entry, "sign": sign}
                   for codes, does, entry, sign in KEYMAP],
        "action_names": list(ACTION_NAMES), "action_ranges": [list(r) for r in ACTION_RANGES],
        "perception_names": list(PERCEPTION_NAMES), "head_rate": HEAD_RATE,
        "turn_rate": TURN_RATE, "modes": list(MODES), "clock": loop_settings.clock,
        "autonomy": kind,
        "field": {"length": f.length, "width": f.width, "goal_width": f.goal_width},
        "locations": [{"index": s.index, "name": s.name} for s in START_LOCATIONS],
    }


def _session_dir(out: Path) -> Path:
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    n = 0
    while (out / f"session-{n}").exists():
        n += 1
    d = out / f"session-{n}"
    d.mkdir()
    return d


async def _serve(session: Any, args: argparse.Namespace) -> int:
    from simulator.teach.server import PageServer

    loop = session.loop
    stop = asyncio.Event()
    got: list[int] = []

    def on_signal(signum: int) -> None:
        got.append(signum)
        stop.set()

    aio = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        aio.add_signal_handler(signum, on_signal, signum)
    host, port = args.http
    server = PageServer(host, port, config_for_page(loop.s, session.autonomy.kind),
                        submit=loop.inbox.put, handle=session.handle, snapshot=session.snapshot,
                        image=session.image, refused=session.refused,
                        limits={"half_length": session.sim.cfg.field.length / 2,
                                "half_width": session.sim.cfg.field.width / 2})
    loop.on_tick = server.publish_tick

    def ready(url: str) -> None:
        print(f"roger teach: the page is at {url} (session in {session.out}; Ctrl-C stops)",
              flush=True)

    await server.serve(ready, stop)
    return 128 + (got[0] if got else signal.SIGINT)


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C (130) or SIGTERM (143); 2 for a bad ``--out``."""
    from simulator.teach.loop import LoopSettings
    from simulator.teach.session import SessionSettings, TeachSession

    try:
        out = _session_dir(args.out)
    except (ValueError, OSError) as exc:
        print(f"roger teach: {exc}", file=sys.stderr)
        return 2
    settings = SessionSettings(out=out, vision=args.vision, time_limit=args.time_limit,
                               loop=LoopSettings(clock=args.clock, seed=args.seed,
                                                 location=args.location, mode=args.mode))
    session = TeachSession(settings)
    code = 130
    try:
        session.start()
        code = asyncio.run(_serve(session, args))
    except KeyboardInterrupt:  # Ctrl-C while starting
        code = 130
    finally:
        summary = session.close()
        (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", "utf-8")
        print(f"roger teach: stopped; {summary.get('ticks', 0)} ticks, "
              f"{summary.get('counts', {}).get('pairs_sent', 0)} pairs taught, "
              f"{summary.get('counts', {}).get('corrections', 0)} corrections; "
              f"session in {out}", flush=True)
    return code

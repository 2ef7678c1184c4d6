"""``roger view``: a live Foxglove view of a ROGER session (WebSocket), or a recorded one (MCAP).

Live: subscribes to ``roger/<robot>/*`` over Zenoh (as the operator tools do), converts every
message with :class:`simulator.view.scene.Converter` and serves the result on Foxglove's
WebSocket protocol (``foxglove-sdk``; open ``ws://127.0.0.1:8765`` in the Foxglove app), and
with ``--record OUT.mcap`` writes the same channels to an MCAP file as well. Offline: ``roger
view LOG.mcap [--out DIR]`` converts a recorded session (the daemon's or ``roger record``'s)
into the same channels with the recorded log times and its ``roger.session`` metadata, so a
recorded session looks like a live one (``DIR/<LOG's name>.foxglove.mcap``; beside the log
without ``--out``; never over an existing file without ``--force``; ``--log FILE`` is the
deprecated spelling of the positional LOG).

Clients: the server speaks Foxglove's WebSocket protocol as ``foxglove-sdk`` 0.30 serves it,
subprotocol ``foxglove.sdk.v1`` (the Foxglove app, desktop or web, of 2025 on). A client that
asks only for the older ``foxglove.websocket.v1`` (Foxglove Studio 1.x, Lichtblick, the
``foxglove-websocket`` Python client) is refused with HTTP 400: record with ``--record`` or
convert the log and open the MCAP file instead (``docs/live-view.md``).

The view is a separate, optional process: the daemon and the simulator never import
``foxglove`` (install it with ``pip install -e '.[live]'``). The scene needs the simulator's
ground truth: run ``roger sim --truth`` (``roger up`` does when ``[view]`` is on).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import time
from pathlib import Path
from typing import Any

from roger_daemon.console import UsageError
from roger_daemon.tools.common import add_connection_args, port, seconds

__all__ = ["Sinks", "configure", "convert_log", "run"]

log = logging.getLogger("roger.view")

_NUM = {"type": "number"}
_BY_ACTION = {"type": "object", "description": "one number per action name (protocols/AIBO.md)",
              "additionalProperties": _NUM}
#: the JSON channels' schemas (name, jsonschema)
JSON_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "/roger/command": ("roger.view.Command", {"type": "object", "properties": {
        "tick": _NUM, "source": {"type": "string"}, "y": _BY_ACTION}}),
    "/roger/prediction": ("roger.view.Prediction", {"type": "object", "properties": {
        "tick": _NUM, "expert": _NUM, "updates": _NUM, "latency_ms": _NUM,
        "mode": {"type": "string"}, "mean": _BY_ACTION, "var": _BY_ACTION, "std": _BY_ACTION}}),
    "/roger/expert": ("roger.view.Expert", {"type": "object", "properties": {
        "tick": _NUM, "expert": _NUM, "expert_label": {"type": "string"},
        "subtask": {"type": "string"}, "experts": _NUM}}),
}


#: the WebSocket subprotocol the server accepts (foxglove-sdk 0.30); docs/live-view.md
SUBPROTOCOL = "foxglove.sdk.v1"


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger view``."""
    parser.add_argument("log_file", nargs="?", type=Path, default=None, metavar="LOG",
                        help="offline: convert this recorded session (MCAP) into Foxglove "
                             "channels instead of going live")
    parser.add_argument("--robot", default="aibo", help="robot id to show (default aibo)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address of the WebSocket server (default 127.0.0.1, this host only)")
    parser.add_argument("--port", type=port, default=8765,
                        help="port of the WebSocket server (default 8765, Foxglove's; 0: any)")
    parser.add_argument("--record", type=Path, default=None, metavar="FILE",
                        help="also write the live channels to this MCAP file")
    parser.add_argument("--log", type=Path, default=None, metavar="FILE",
                        help="deprecated spelling of the positional LOG")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="offline: directory for LOG's Foxglove MCAP, "
                             "<LOG's name>.foxglove.mcap (default: beside LOG; --out FILE.mcap, "
                             "the old form, is deprecated but still works)")
    parser.add_argument("--force", action="store_true",
                        help="offline: overwrite an existing output file")
    parser.add_argument("--duration", type=seconds, default=0.0, metavar="S",
                        help="live: stop after S seconds (default: until Ctrl-C)")
    add_connection_args(parser, timeout=5.0)


def _foxglove() -> Any:
    try:
        import foxglove
    except ImportError:
        raise UsageError("roger view needs the foxglove-sdk package: pip install -e '.[live]' "
                         "(or pip install foxglove-sdk)") from None
    return foxglove


class Sinks:
    """One ``foxglove.Context``: a channel per topic, fanning out to its server and/or MCAP."""

    def __init__(self) -> None:
        fg = _foxglove()
        self.fg = fg
        self.context = fg.Context()
        self.channels: dict[str, Any] = {}

    def _channel(self, topic: str, msg: Any) -> Any:
        ch = self.channels.get(topic)
        if ch is None:
            import foxglove.channels as fc

            if isinstance(msg, dict):
                name, schema = JSON_SCHEMAS.get(topic, ("roger.view.Json", {"type": "object"}))
                ch = self.fg.Channel(topic, message_encoding="json", context=self.context,
                                     schema=self.fg.Schema(name=name, encoding="jsonschema",
                                                           data=json.dumps(schema).encode()))
            else:
                cls = getattr(fc, type(msg).__name__ + "Channel")
                ch = cls(topic, context=self.context)
            self.channels[topic] = ch
        return ch

    def log(self, pairs: list[tuple[str, Any]], ns: int) -> None:
        """Write ``(topic, message)`` pairs to the MCAP at log time ``ns``."""
        for topic, msg in pairs:
            self._channel(topic, msg).log(msg, log_time=ns)


def _decoded(key: str, payload: bytes) -> tuple[str, dict[str, Any]] | None:
    from protocols import keys
    from protocols.errors import ProtocolError
    from roger_daemon.tools.common import decode_sample

    try:
        _, kind = keys.parse(key)
        return kind, decode_sample(key, payload)
    except ProtocolError:
        return None


def convert_log(src: Path, out: Path, robot: str | None = None) -> dict[str, int]:
    """Convert a recorded session to Foxglove channels in ``out`` (written atomically, with
    the log's metadata records); messages per topic."""
    from mcap.reader import make_reader

    from roger_daemon.atomic import atomic_write
    from simulator.view.scene import Converter

    sinks = Sinks()
    conv = Converter()
    counts: dict[str, int] = {}
    with atomic_write(out) as f:
        writer = sinks.fg.open_mcap(f, context=sinks.context)
        try:
            with src.open("rb") as fh:
                reader = make_reader(fh)
                for rec in reader.iter_metadata():  # roger.session: config, params, versions
                    writer.write_metadata(rec.name, dict(rec.metadata))
            with src.open("rb") as fh:
                for _schema, channel, message in make_reader(fh).iter_messages(
                        log_time_order=True):
                    got = _decoded(channel.topic, message.data)
                    if got is None or (robot and got[1]["robot"] != robot):
                        continue
                    pairs = conv.convert(got[0], got[1], message.log_time)
                    sinks.log(pairs, message.log_time)
                    for topic, _ in pairs:
                        counts[topic] = counts.get(topic, 0) + 1
        finally:
            writer.close()
    return counts


def _offline(args: argparse.Namespace) -> int:
    """Convert the log (positional, or the deprecated ``--log``) into ``--out DIR``."""
    from roger_daemon.recording.mcapio import not_an_mcap_file
    from roger_daemon.recording.outputs import output_file

    if args.log is not None:
        print("roger view: warning: --log FILE is deprecated; give the log as the first "
              "argument: roger view FILE", file=sys.stderr)
    src: Path = args.log_file or args.log
    why = not_an_mcap_file(src)
    if why:
        raise UsageError(f"LOG: {why}")
    out = output_file("view", args.out, src.with_name(src.stem + ".foxglove.mcap"))
    if out.exists() and not args.force:
        raise UsageError(f"--out: {out} exists; pass --force to overwrite it")
    if out.resolve() == src.resolve():
        raise UsageError(f"--out: {out} is the log itself")
    out.parent.mkdir(parents=True, exist_ok=True)
    counts = convert_log(src, out, args.robot)
    print(f"wrote {out}: " + ", ".join(f"{t} {n}" for t, n in sorted(counts.items())))
    return 0


def run(args: argparse.Namespace) -> int:
    """Live until Ctrl-C (or ``--duration``), or convert a log."""
    if args.log_file is not None and args.log is not None:
        raise UsageError("give the log once: roger view LOG (--log is its deprecated spelling)")
    if args.log_file is not None or args.log is not None:
        return _offline(args)
    if args.out is not None:
        raise UsageError("--out is for a log's conversion: roger view LOG --out DIR")
    return _live(args)


def _live(args: argparse.Namespace) -> int:
    from protocols import keys
    from roger_daemon.tools.common import Listener, open_from_args, settings_from_args
    from simulator.view.scene import Converter

    try:
        keys.validate_robot_id(args.robot)
    except ValueError as exc:
        raise UsageError(f"--robot: {exc}") from None
    # SIGTERM (roger up's stop) from now on ends the loop below and closes what it opened,
    # however early it comes: exit 0 (docs/cli.md, exit statuses), never killed mid-setup
    stop: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, _frame: stop.append(signum))
    sinks = Sinks()
    try:
        server = sinks.fg.start_server(name=f"roger view {args.robot}", host=args.host,
                                       port=args.port, context=sinks.context)
    except Exception as exc:  # the SDK raises its own error for a busy port or a bad host
        raise UsageError(f"cannot serve the WebSocket on {args.host}:{args.port}: {exc}") from None
    if args.record is not None and args.record.exists() and not args.force:
        server.stop()
        raise UsageError(f"--record: {args.record} exists; pass --force to overwrite it")
    writer = (sinks.fg.open_mcap(str(args.record), allow_overwrite=True, context=sinks.context)
              if args.record else None)
    session = open_from_args(args)
    listener = Listener(session, f"{keys.ROOT}/{args.robot}/*", capacity=8192)
    log.info("serving the Foxglove WebSocket on ws://%s:%d (robot %s)%s", args.host,
             server.port, args.robot, f", recording to {args.record}" if args.record else "")
    print(f"roger view: ws://{args.host}:{server.port}", flush=True)
    conv = Converter()
    start = time.monotonic()
    heard = False
    try:
        while not stop and (not args.duration or time.monotonic() - start < args.duration):
            s = listener.get(0.2)
            if s is None:
                if not heard and args.timeout and time.monotonic() - start >= args.timeout:
                    heard = True  # warn once
                    log.warning("nothing received on %s/%s/* within %g s from %s: is a "
                                "daemon or simulator running there (roger list)?", keys.ROOT,
                                args.robot, args.timeout,
                                ", ".join(settings_from_args(args).connect or ("(file)",)))
                continue
            heard = True
            got = _decoded(s.key, s.payload)
            if got is not None:
                ns = time.time_ns()
                sinks.log(conv.convert(got[0], got[1], ns), ns)
    finally:
        listener.close()
        session.close()
        if writer is not None:
            writer.close()
        server.stop()
    return 0  # SIGTERM is a supervisor's stop (roger up): 0; Ctrl-C raises and exits 130

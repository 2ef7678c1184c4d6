"""``roger sim``'s command line: the arguments, the task config and the episode plan they give."""

from __future__ import annotations

import argparse
from dataclasses import replace

from roger_daemon.zenoh_session import DAEMON_ENDPOINT as ZENOH_DAEMON_ENDPOINT
from simulator.config import CameraConfig, SimConfig, load_config
from simulator.episodes import parse_locations
from simulator.transport import add_zenoh_args

__all__ = ["DAEMON_ENDPOINT", "DEFAULT_LISTEN", "configure", "episode_plan", "sim_config"]

DEFAULT_LISTEN = "tcp/127.0.0.1:7450"
#: The daemon's default listen endpoint (:data:`roger_daemon.zenoh_session.DAEMON_ENDPOINT`);
#: unreachable is fine (peers keep retrying in the background).
DAEMON_ENDPOINT = ZENOH_DAEMON_ENDPOINT


def configure(parser: argparse.ArgumentParser) -> None:
    """Command-line arguments of ``roger sim``."""
    parser.add_argument("--robot", default="aibo",
                        help="robot id in the key expressions (the model is always the AIBO)")
    parser.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                        help="lockstep: wait for command(t) before stepping (default); "
                             "realtime: step at 30 Hz whatever arrives")
    parser.add_argument(
        "--vision",
        choices=("rendered", "fast"),
        default=None,
        help="rendered segmentation (default) or fast analytic projection",
    )
    parser.add_argument("--width", type=int, default=None, help="camera width (default 208)")
    parser.add_argument("--height", type=int, default=None, help="camera height (default 160)")
    parser.add_argument("--config", default=None, help="task TOML (e.g. configs/aibo.toml)")
    parser.add_argument(
        "--locations", default="all", help="start locations: 'all' or e.g. '0,3,7' or '0-4' (0..12)"
    )
    parser.add_argument("--episodes-per-location", type=int, default=1,
                        help="episodes run from each start location (default 1)")
    parser.add_argument("--max-episodes", type=int, default=0, help="cap (0: no cap)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the start poses' noise and of the vision (default 0)")
    parser.add_argument("--episode-duration", "--time-limit", dest="time_limit", type=float,
                        default=None, metavar="S",
                        help="an episode's limit in seconds of sim time (150; --time-limit: "
                             "the deprecated spelling)")
    parser.add_argument(
        "--command-timeout",
        type=float,
        default=2.0,
        help="lockstep: seconds to wait for command(t) before a hold tick",
    )
    parser.add_argument(
        "--wait-subscribers",
        type=float,
        default=30.0,
        help="seconds to wait for a perception subscriber before starting",
    )
    parser.add_argument(
        "--wait-peers",
        type=int,
        default=0,
        help="also wait until this many Zenoh peers are connected (e.g. 2: controller and "
        "daemon) before the first episode",
    )
    parser.add_argument("--results", default=None, help="write the results JSON here")
    parser.add_argument("--truth", action="store_true", help="publish a 'truth' event every tick")
    add_zenoh_args(parser, listen=(DEFAULT_LISTEN,), connect=(DAEMON_ENDPOINT,))


def sim_config(args: argparse.Namespace) -> SimConfig:
    """The task config the command line asked for (``--config``, then the flags on top)."""
    cfg = load_config(args.config)
    if args.vision:
        cfg = replace(cfg, vision=args.vision)
    if args.width or args.height:
        cam = cfg.camera
        cfg = replace(
            cfg,
            camera=CameraConfig(
                width=args.width or cam.width,
                height=args.height or cam.height,
                hfov=cam.hfov,
                near=cam.near,
                far=cam.far,
                min_pixels=cam.min_pixels,
            ),
        )
    if args.time_limit is not None:
        cfg = replace(cfg, episode=replace(cfg.episode, time_limit=args.time_limit))
    return cfg


def episode_plan(args: argparse.Namespace) -> list[tuple[int, int]]:
    """``(location, repetition)`` of every episode to run, in order (location major)."""
    locs = parse_locations(args.locations)
    if args.episodes_per_location < 1:
        raise ValueError("--episodes-per-location must be >= 1")
    plan = [(loc, rep) for loc in locs for rep in range(args.episodes_per_location)]
    if args.max_episodes > 0:
        plan = plan[: args.max_episodes]
    return plan

"""``roger sim``: the AIBO soccer simulator as a Zenoh process.

Publishes ``perception`` (23-D, ``t`` = the episode's sim time, 0 on its first tick; ``tick``
counts up over the whole run) and ``episode`` events; executes ``command``.

* ``--clock lockstep``: after publishing perception(t) it waits for command(t) (matched by
  tick), re-publishing perception(t) every 0.25 s; after ``--command-timeout`` it counts a
  timeout and executes a *hold* command (stand still, head and tail where they are, no motion).
* ``--clock realtime``: 30 Hz wall clock; each tick executes the newest command received
  (hold until the first one), steps, publishes. Overruns are counted.

Episodes: every location of ``--locations`` is run ``--episodes-per-location`` times (location
major), at most ``--max-episodes``; the process then publishes a final ``end`` event with
``data.run_complete = true`` (again every 0.25 s while its subscribers stay, at most 2 s:
events go out DROP like every stream), prints one JSON object (``episodes`` and
``summary``) on stdout, writes it to ``--results FILE`` if asked, and exits 0. Episode events:

* ``start``: data ``location``, ``location_name``, ``repetition``, ``seed``, ``tick`` (first),
  ``robot_x``, ``robot_y``, ``robot_yaw``, ``ball_x``, ``ball_y``;
* ``goal`` | ``own_goal`` | ``out`` | ``timeout``: the outcome, data ``location``,
  ``sim_time_s``;
* ``end``: data = the episode's result record (see ``EpisodeResult.to_map``) plus the
  transport counters of that episode;
* ``truth`` (only with ``--truth``): per tick, robot pose and ball position.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from protocols import Command, EpisodeEvent, Perception, keys
from protocols.aibo import DIMS
from roger_daemon.atomic import write_json
from simulator.config import SimConfig
from simulator.episodes import START_LOCATIONS, EpisodeResult, SoccerSim
from simulator.sim_args import DAEMON_ENDPOINT, DEFAULT_LISTEN, configure, episode_plan, sim_config
from simulator.transport import (
    InvalidCounter,
    StopFlag,
    Subscription,
    config_from_args,
    episode_publisher,
    has_subscribers,
    open_session,
    publisher,
    put,
    wait_for,
)

__all__ = ["DAEMON_ENDPOINT", "DEFAULT_LISTEN", "configure", "run"]

log = logging.getLogger("roger.sim")

RESEND_S = 0.25
#: After the final episode event, wait at most this long (s) for its subscribers to leave.
LINGER_S = 2.0


class SimNode:
    """The process: one session, one loop."""

    def __init__(self, args: argparse.Namespace, cfg: SimConfig, stop: StopFlag) -> None:
        self.args = args
        self.cfg = cfg
        self.stop = stop
        self.robot = keys.validate_robot_id(args.robot)
        self.sim = SoccerSim(cfg)
        self.tick = 0
        self.invalid = InvalidCounter("sim")
        self.counters = {
            "command_timeouts": 0,
            "stale_commands": 0,
            "future_commands": 0,
            "hold_ticks": 0,
            "overruns": 0,
            "resends": 0,
        }
        self.last_cmd = np.zeros(DIMS.y)

    def _hold(self) -> np.ndarray:
        """Stand still, head and tail where they are, no motion."""
        y = np.zeros(DIMS.y)
        y[3:8] = self.sim.world.joint_angles()
        return y

    def run(self, session: Any) -> dict[str, Any]:
        args = self.args
        self.pub_x = publisher(session, keys.perception(self.robot))
        self.pub_ep = episode_publisher(session, self.robot)
        self.cmds = Subscription(session, self.robot, "command", DIMS, self.invalid, capacity=256)
        t_wait = time.monotonic()
        while not self.stop.stopped and time.monotonic() - t_wait < args.wait_subscribers:
            peers = len(list(session.info.peers_zid()))
            if has_subscribers(self.pub_x) and peers >= args.wait_peers:
                if args.wait_peers > 0:
                    time.sleep(0.3)  # let the peers' subscriber declarations arrive
                break
            time.sleep(0.02)
        else:
            if not self.stop.stopped:
                log.warning(
                    "no perception subscriber (or fewer than %d peers) after %.1f s; "
                    "starting anyway",
                    args.wait_peers,
                    args.wait_subscribers,
                )
        results: list[EpisodeResult] = []
        t0 = time.monotonic()
        ticks0 = self.tick
        for k, (loc, rep) in enumerate(episode_plan(args)):
            if self.stop.stopped:
                break
            res = self._episode(k, loc, rep)
            results.append(res)
            log.info(
                "episode %d location %d rep %d: %s after %.1f s sim time",
                k,
                loc,
                rep,
                res.outcome,
                res.sim_time_s,
            )
        wall = time.monotonic() - t0
        summary = self._summary(results, wall, self.tick - ticks0)
        final = EpisodeEvent(
            self.robot,
            self.tick,
            0.0,
            event="end",
            episode=len(results),
            data={
                "run_complete": True,
                **{k: v for k, v in summary.items() if not isinstance(v, dict)},
            },
        )
        put(self.pub_ep, final)
        # Linger so that the final event reaches the controller before the session closes
        # (closing drops what is still queued; a controller with --exit-when-done waits for
        # this event and then leaves): until no subscriber of the episode events is left, at
        # most LINGER_S (a recorder stays to the end). The event goes out DROP, so it is sent
        # again every RESEND_S meanwhile (a controller leaves on the first copy it sees).
        deadline = time.monotonic() + LINGER_S
        resend = time.monotonic() + RESEND_S
        while has_subscribers(self.pub_ep) and time.monotonic() < deadline:
            time.sleep(0.02)
            if time.monotonic() >= resend:
                put(self.pub_ep, final)
                resend += RESEND_S
        self.cmds.close()
        return {
            "schema": "roger.sim.results/1",
            "robot": self.robot,
            "clock": args.clock,
            "vision": self.cfg.vision,
            "camera": [self.cfg.camera.width, self.cfg.camera.height],
            "seed": args.seed,
            "episodes": [r.to_map() for r in results],
            "summary": summary,
        }

    def _summary(self, results: list[EpisodeResult], wall: float, ticks: int) -> dict[str, Any]:
        outcomes: dict[str, int] = {}
        for r in results:
            outcomes[r.outcome] = outcomes.get(r.outcome, 0) + 1
        n = len(results)
        succ = sum(r.success for r in results)
        return {
            "episodes": n,
            "successes": succ,
            "success_rate": succ / n if n else 0.0,
            "outcomes": outcomes,
            "ticks": ticks,
            "wall_s": round(wall, 3),
            "ticks_per_s": round(ticks / wall, 1) if wall > 0 else 0.0,
            "invalid_messages": self.invalid.total(),
            "stopped": self.stop.stopped,
            **self.counters,
        }

    def _episode(self, k: int, loc: int, rep: int) -> EpisodeResult:
        sim = self.sim
        x = sim.reset(loc, self.args.seed, rep)
        self.last_cmd = self._hold()
        before = dict(self.counters)
        truth = sim.truth()
        put(
            self.pub_ep,
            EpisodeEvent(
                self.robot,
                self.tick,
                0.0,
                event="start",
                episode=k,
                data={
                    "location": loc,
                    "location_name": START_LOCATIONS[loc].name,
                    "repetition": rep,
                    "seed": self.args.seed,
                    "tick": self.tick,
                    "clock": self.args.clock,
                    **{
                        n: truth[n] for n in ("robot_x", "robot_y", "robot_yaw", "ball_x", "ball_y")
                    },
                },
            ),
        )
        lockstep = self.args.clock == "lockstep"
        period = self.cfg.episode.dt
        next_deadline = time.monotonic()
        while True:
            t_sim = sim.time
            perception = Perception(self.robot, self.tick, t_sim, x=x)
            put(self.pub_x, perception)
            if lockstep:
                y = self._await_command(perception)
            else:
                next_deadline += period
                y = self._newest_command()
            if y is None:
                self.counters["hold_ticks"] += 1
                y = self._hold()
            outcome = sim.step(y)
            if self.args.truth:
                put(
                    self.pub_ep,
                    EpisodeEvent(
                        self.robot, self.tick, t_sim, event="truth", episode=k, data=sim.truth()
                    ),
                )
            self.tick += 1
            if outcome is None and self.stop.stopped:
                sim.stop()
                outcome = "stopped"
            if outcome is not None:
                break
            if not lockstep:
                delay = next_deadline - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                else:
                    self.counters["overruns"] += 1
                    if delay < -1.0:  # far behind: do not try to catch up
                        next_deadline = time.monotonic()
            x = sim.perceive()
        res = sim.result(k)
        if outcome != "stopped":
            put(
                self.pub_ep,
                EpisodeEvent(
                    self.robot,
                    self.tick,
                    sim.time,
                    event=outcome,
                    episode=k,
                    data={"location": loc, "sim_time_s": round(sim.time, 4)},
                ),
            )
        delta = {name: self.counters[name] - before[name] for name in self.counters}
        res.counters.update(delta)
        put(
            self.pub_ep,
            EpisodeEvent(
                self.robot, self.tick, sim.time, event="end", episode=k, data=res.to_map()
            ),
        )
        return res

    def _take(self, want: int) -> np.ndarray | None:
        while (m := self.cmds.poll()) is not None:
            assert isinstance(m, Command)
            if m.tick == want:
                return np.array(m.y)
            if m.tick < want:
                self.counters["stale_commands"] += 1
            else:
                self.counters["future_commands"] += 1
        return None

    def _await_command(self, perception: Perception) -> np.ndarray | None:
        deadline = time.monotonic() + self.args.command_timeout
        while not self.stop.stopped:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            y = wait_for(lambda: self._take(perception.tick), min(RESEND_S, remaining), self.stop)
            if y is not None:
                self.last_cmd = y
                return y
            if time.monotonic() < deadline and not self.stop.stopped:
                self.counters["resends"] += 1
                put(self.pub_x, perception)
        if not self.stop.stopped:
            self.counters["command_timeouts"] += 1
        return None

    def _newest_command(self) -> np.ndarray | None:
        newest: Command | None = None
        for m in self.cmds.drain():
            assert isinstance(m, Command)
            if newest is None or m.tick >= newest.tick:
                newest = m
        if newest is not None:
            self.last_cmd = np.array(newest.y)
            return self.last_cmd
        return self.last_cmd if self.tick > 0 else None


def run(args: argparse.Namespace) -> int:
    """Run the planned episodes; print the results JSON; exit 0 (1 on bad arguments)."""
    try:
        cfg = sim_config(args)
        episode_plan(args)
    except (ValueError, OSError) as exc:
        print(f"roger sim: {exc}", file=sys.stderr)
        return 2
    stop = StopFlag()
    node = SimNode(args, cfg, stop)
    session = open_session(config_from_args(args))
    try:
        out = node.run(session)
    finally:
        try:
            session.close()
        except Exception as exc:  # zenoh may time out closing; nothing left to save
            log.warning("closing the zenoh session: %s", exc)
        node.sim.close()
    text = json.dumps(out)
    if args.results:
        path = Path(args.results)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json(path, out)
    print(text, flush=True)
    return 0

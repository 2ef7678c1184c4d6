"""The teaching loop: the simulator stepped at 30 Hz, the teacher's and the robot's commands.

One thread owns the simulator (:class:`~simulator.episodes.SoccerSim`) and runs
:meth:`TeachLoop.run`; the page's server hands it the teacher's commands
(:class:`TeacherInbox`) and requests (:meth:`TeachLoop.request`), and reads its newest
:meth:`TeachLoop.snapshot`. Each tick, as ``roger sim`` and a controller would over Zenoh
(the daemon is a separate ``roger daemon`` process, reached through
:class:`~roger_daemon.client.RobotClient`):

1. perception(t) to the daemon; the newest prediction back (lockstep: the prediction of t);
2. the robot's command: :class:`~simulator.teach.autonomy.Autonomy` (the learned
   transitions of the daemon's model) on that multimap;
3. the teacher's command (lockstep: the one answering tick t): in **demonstrate** it drives
   and every pair is learned; in **autonomous** the robot drives and nothing is learned; in
   **correct** the robot drives unless the teacher holds a control key, and then the
   teacher's command replaces the robot's and that pair is learned as a correction (HG-DAgger);
4. action(t) (``source`` teacher, ``correction``) when learned; command(t) with ``source``
   ``teacher`` or ``robot``; the simulator executes it.

Episodes end as in ``roger sim`` (goal, own goal, out, time limit) and the next one starts at
once, at the next start location or where the page asked.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from protocols import Command, EpisodeEvent, Prediction, keys
from simulator.episodes import START_LOCATIONS, SoccerSim, StartLocation
from simulator.teach.autonomy import Autonomy, hold_command
from simulator.teach.channel import MODES, PageInput
from simulator.transport import episode_publisher, publisher, put

__all__ = ["LoopSettings", "TeachLoop", "TeacherInbox"]

log = logging.getLogger("roger.teach")
FloatArray = npt.NDArray[np.float64]
#: A realtime teacher command older than this (s) counts as released (a page that went away
#: must not keep the robot walking).
STALE_S = 0.5


@dataclass(frozen=True)
class LoopSettings:
    """How the loop runs: its clock, seed, first location, lockstep waits."""

    clock: str = "realtime"
    seed: int = 0
    location: int = 0
    mode: str = "demonstrate"
    teacher_timeout_s: float = 10.0
    prediction_timeout_s: float = 10.0


class TeacherInbox:
    """The teacher's newest command, handed from the page's server to the loop."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._latest: PageInput | None = None
        self.received = 0
        self.timeouts = 0
        #: (key press -> receipt, key press -> executed) in ms, of commands carrying sent_ms
        self.to_received: deque[float] = deque(maxlen=5000)
        self.to_applied: deque[float] = deque(maxlen=5000)

    def put(self, cmd: PageInput) -> None:
        """A command from a page (any thread)."""
        with self._cond:
            self._latest = cmd
            self.received += 1
            if cmd.sent_ms is not None:
                self.to_received.append(cmd.received * 1e3 - cmd.sent_ms)
            self._cond.notify_all()

    def latest(self) -> PageInput | None:
        """The newest command, ``None`` if none or stale (realtime)."""
        with self._cond:
            c = self._latest
        if c is None or time.time() - c.received > STALE_S:
            return None
        return c

    def wait_tick(self, tick: int, timeout: float, stop: threading.Event,
                  pending: Callable[[], bool] = lambda: False) -> PageInput | None:
        """The command answering ``tick`` (lockstep); ``None`` after ``timeout`` s, or at
        once when ``pending()`` (a request such as a mode change is waiting)."""
        end = time.monotonic() + timeout
        with self._cond:
            while not stop.is_set() and not pending():
                c = self._latest
                if c is not None and c.tick is not None and c.tick >= tick:
                    return c
                left = end - time.monotonic()
                if left <= 0:
                    self.timeouts += 1
                    return None
                self._cond.wait(min(left, 0.2))
        return None

    def wake(self) -> None:
        """Wake a :meth:`wait_tick` (a request arrived)."""
        with self._cond:
            self._cond.notify_all()

    def applied(self, cmd: PageInput) -> None:
        """``cmd`` is executed now (its first tick only)."""
        if cmd.sent_ms is not None:
            with self._cond:
                self.to_applied.append(time.time() * 1e3 - cmd.sent_ms)


class TeachLoop:
    """The loop (module docstring). ``client`` is a connected RobotClient of the daemon."""

    def __init__(self, settings: LoopSettings, sim: SoccerSim, client: Any,
                 autonomy: Autonomy | None = None,
                 on_tick: Callable[[dict[str, Any]], None] | None = None) -> None:
        self.s = settings
        self.sim = sim
        self.client = client
        self.robot = client.robot
        self.autonomy = autonomy or Autonomy()
        self.inbox = TeacherInbox()
        self.on_tick = on_tick
        #: called in the loop's thread after every step (the camera image is rendered there)
        self.after_step: Callable[[], None] | None = None
        #: called when the teacher releases the robot after a correction
        self.on_correction_end: Callable[[], None] | None = None
        self._correcting = False
        self.stop = threading.Event()
        self.mode = settings.mode
        self.tick = 0
        self.episode = -1
        self.counts: Counter[str] = Counter()
        self.outcomes: Counter[str] = Counter()
        self.episodes: deque[dict[str, Any]] = deque(maxlen=200)
        self.tick_times: deque[float] = deque(maxlen=200)  # monotonic s of the newest ticks
        self._requests: deque[PageInput] = deque()
        self._lock = threading.Lock()
        self._snapshot: dict[str, Any] = {}
        self._next_location = settings.location
        self._last_applied: PageInput | None = None
        # the simulator's own outputs, published as roger sim publishes them (the daemon's
        # messages go through the client)
        self._pub_cmd = publisher(client.session, keys.command(self.robot))
        self._pub_ep = episode_publisher(client.session, self.robot)
        self.x = self._start_episode(settings.location, None)

    # -- the server's side -----------------------------------------------------------------

    def request(self, req: PageInput) -> None:
        """A mode change, reset or ball placement, carried out before the next tick."""
        with self._lock:
            self._requests.append(req)
        self.inbox.wake()

    def snapshot(self) -> dict[str, Any]:
        """The newest tick's state (what the page shows)."""
        with self._lock:
            return self._snapshot

    # -- episodes ----------------------------------------------------------------------------

    def _start_episode(self, location: int, start: StartLocation | None) -> FloatArray:
        self.episode += 1
        x = self.sim.reset(location, self.s.seed, self.episode, start)
        self._next_location = (location + 1) % len(START_LOCATIONS)
        self.autonomy.reset()
        self._episode_start = True
        truth = self.sim.truth()
        data = {"location": location, "location_name": (start or START_LOCATIONS[location]).name,
                "repetition": self.episode, "seed": self.s.seed, "tick": self.tick,
                "clock": self.s.clock,
                **{n: truth[n] for n in ("robot_x", "robot_y", "robot_yaw", "ball_x", "ball_y")}}
        put(self._pub_ep, EpisodeEvent(self.robot, self.tick, 0.0, event="start",
                                       episode=self.episode, data=data))
        return x

    def _end_episode(self, outcome: str) -> None:
        res = self.sim.result(self.episode)
        self.outcomes[outcome] += 1
        record = {**res.to_map(), "mode": self.mode}
        self.episodes.append(record)
        for event, data in ((outcome, {"location": res.location,
                                       "sim_time_s": round(res.sim_time_s, 4)}),
                            ("end", record)):
            if event in ("goal", "own_goal", "out", "timeout", "end"):
                put(self._pub_ep, EpisodeEvent(self.robot, self.tick, self.sim.time,
                                               event=event, episode=self.episode, data=data))
        log.info("episode %d location %d (%s): %s after %.1f s", self.episode, res.location,
                 self.mode, outcome, res.sim_time_s)
        if self.on_tick is not None:
            self.on_tick({"type": "episode", **record})

    def _place_ball(self, ball: tuple[float, float]) -> FloatArray:
        x, y, yaw = self.sim.world.robot_pose()
        here = StartLocation(self.sim.location, "placed", (x, y, math.degrees(yaw)), ball,
                             "placed from the page")
        self.sim.stop()
        self._end_episode("stopped")
        return self._start_episode(self.sim.location, here)

    def _apply_requests(self) -> None:
        with self._lock:
            reqs = list(self._requests)
            self._requests.clear()
        for r in reqs:
            if r.type == "mode" and r.mode in MODES and r.mode != self.mode:
                log.info("mode %s -> %s", self.mode, r.mode)
                self.mode = r.mode
            elif r.type == "reset":
                self.sim.stop()
                self._end_episode("stopped")
                loc = self._next_location if r.location is None else r.location
                self.x = self._start_episode(loc, None)
            elif r.type == "place_ball" and r.ball is not None:
                self.x = self._place_ball(r.ball)

    # -- one tick ----------------------------------------------------------------------------

    def _prediction(self, lockstep: bool) -> Prediction | None:
        if lockstep:
            try:
                got: Prediction = self.client.wait_prediction(self.tick,
                                                              self.s.prediction_timeout_s)
                return got
            except TimeoutError:
                self.counts["prediction_timeouts"] += 1
                return None
        pred: Prediction | None = self.client.latest_prediction()
        return pred

    def _teacher(self, lockstep: bool) -> PageInput | None:
        if lockstep:
            before = self.inbox.timeouts
            got = self.inbox.wait_tick(self.tick, self.s.teacher_timeout_s, self.stop,
                                       lambda: bool(self._requests))
            self.counts["teacher_timeouts"] += self.inbox.timeouts - before
            return got
        return self.inbox.latest()

    def _decide(self, x: FloatArray, robot_y: FloatArray, teacher: PageInput | None
                ) -> tuple[FloatArray, str, bool, bool]:
        """(command, source, learned, correction) of this tick."""
        if self.mode == "demonstrate":
            y = np.array(teacher.y) if teacher is not None else hold_command(x)
            return y, "teacher", True, False
        if self.mode == "correct" and teacher is not None and teacher.active:
            return np.array(teacher.y), "teacher", True, True
        return robot_y, "robot", False, False

    def step_once(self) -> None:
        """One tick (module docstring)."""
        self._apply_requests()
        lockstep = self.s.clock == "lockstep"
        x, tick, t = self.x, self.tick, self.sim.time
        self.client.send_perception(tick, x, t=t)
        pred = self._prediction(lockstep)
        robot_y, expert, how = self.autonomy.act(x, pred)
        tick_msg = {"type": "tick", "tick": tick, "t": t, "episode": self.episode,
                    "start": self._episode_start, "mode": self.mode, "x": x.tolist(),
                    "robot_y": robot_y.tolist()}
        if self.on_tick is not None:
            self.on_tick(tick_msg)
        needs_teacher = self.mode in ("demonstrate", "correct")
        teacher = self._teacher(lockstep and needs_teacher)
        y, source, learned, correction = self._decide(x, robot_y, teacher)
        if teacher is not None and source == "teacher" and teacher is not self._last_applied:
            self.inbox.applied(teacher)
            self._last_applied = teacher
        if learned:
            self.client.send_action(tick, y, t=t, source=source, correction=correction)
            self.counts["pairs_sent"] += 1
            self.counts["corrections"] += int(correction)
        self.autonomy.commit(y)  # the executed command drives the acting memories
        put(self._pub_cmd, Command(self.robot, tick, t, y=y, source=source))
        self.counts[f"ticks_{source}"] += 1
        if self._correcting and not correction and self.on_correction_end is not None:
            self.on_correction_end()
        self._correcting = correction
        self._episode_start = False
        outcome = self.sim.step(y)
        self._publish(x, y, pred, teacher, source, robot_y, expert, how)
        if self.after_step is not None:
            self.after_step()
        self.tick += 1
        self.tick_times.append(time.monotonic())
        if self.tick % 300 == 0:
            self.client.trim_predictions(100)
        if outcome is not None:
            self._end_episode(outcome)
            self.x = self._start_episode(self._next_location, None)
        else:
            self.x = self.sim.perceive()

    def _publish(self, x: FloatArray, y: FloatArray, pred: Prediction | None,
                 teacher: PageInput | None, source: str, robot_y: FloatArray, expert: int,
                 how: str) -> None:
        truth = self.sim.truth()
        snap = {
            "tick": self.tick, "t": round(self.sim.time, 3), "episode": self.episode,
            "location": self.sim.location, "mode": self.mode, "x": x.tolist(),
            "command": y.tolist(), "source": source, "robot_y": robot_y.tolist(),
            "teacher_y": None if teacher is None else list(teacher.y),
            "teacher_active": bool(teacher is not None and teacher.active),
            "prediction": None if pred is None else {
                "tick": pred.tick, "mean": pred.mean.tolist(), "var": pred.var.tolist(),
                "expert": pred.expert, "experts": len(pred.multimap), "updates": pred.updates},
            "fsm": {"state": expert, "how": how, **self.autonomy.fitted,
                    "loading": self.autonomy.loading},
            "truth": {k: round(float(v), 4) for k, v in truth.items()},
            "counts": dict(self.counts), "outcomes": dict(self.outcomes),
        }
        with self._lock:
            self._snapshot = snap

    # -- the thread --------------------------------------------------------------------------

    def run(self) -> None:
        """Step until :attr:`stop` is set (realtime: at the simulator's 30 Hz)."""
        period = self.sim.cfg.episode.dt
        deadline = time.monotonic()
        while not self.stop.is_set():
            self.step_once()
            if self.s.clock == "lockstep":
                continue
            deadline += period
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                self.counts["overruns"] += 1
                if delay < -1.0:  # far behind: do not try to catch up
                    deadline = time.monotonic()


def settings_for(clock: str, **kw: Any) -> LoopSettings:
    """:class:`LoopSettings` with ``clock`` and the given fields."""
    return replace(LoopSettings(clock=clock), **kw)

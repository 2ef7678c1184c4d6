"""One ``roger teach`` session: the daemon, the simulator's loop, takes, checkpoints.

:class:`TeachSession` starts ``roger daemon`` (a real subprocess on a free loopback port,
recording the whole session to ``OUT/recordings``, checkpoints in ``OUT/checkpoints``),
connects a :class:`~roger_daemon.client.RobotClient`, builds the simulator and
:class:`~simulator.teach.loop.TeachLoop` and runs the loop in its own thread. It carries out
what the page asks besides commands (:meth:`TeachSession.handle`): modes, resets, the ball,
takes (``roger record`` into ``OUT/takes``, started and stopped from the page), checkpoints,
and on entering autonomous or correct mode (and after each correction) the daemon's learned
transitions loaded from a fresh checkpoint (in the background; the previous ones act meanwhile).
:meth:`TeachSession.close` stops all of it; nothing it started is left running.
"""

from __future__ import annotations

import base64
import io
import logging
import signal
import subprocess
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simulator.teach.autonomy import Autonomy
from simulator.teach.channel import PageInput
from simulator.teach.loop import LoopSettings, TeachLoop

__all__ = ["TASK_LEARNER", "SessionSettings", "TeachSession"]

log = logging.getLogger("roger.teach")
#: The learner's task settings (the goal-scoring experiment's, docs/goal-scoring.md).
TASK_LEARNER = {"novelty_threshold": 1e-3, "particles": 100}


@dataclass(frozen=True)
class SessionSettings:
    """Where the session writes and how its parts run."""

    out: Path
    loop: LoopSettings
    vision: str = "rendered"
    time_limit: float = 60.0
    daemon_port: int = 0
    learner: tuple[tuple[str, Any], ...] = tuple(TASK_LEARNER.items())


class TeachSession:
    """The parts of one session (module docstring); use :meth:`start`, then :meth:`close`."""

    def __init__(self, settings: SessionSettings) -> None:
        self.s = settings
        self.out = settings.out
        self.refused: Counter[str] = Counter()
        self.daemon: Any = None
        self.client: Any = None
        self.sim: Any = None
        self.loop: TeachLoop | None = None
        self.autonomy = Autonomy()
        self.endpoint = ""
        self._thread: threading.Thread | None = None
        self._take: subprocess.Popen[bytes] | None = None
        self._take_log: Any = None
        self.takes: list[str] = []
        self._image_lock = threading.Lock()
        self._image = ""
        self.want_image = threading.Event()
        self._load_lock = threading.Lock()
        self._load_again = False

    # -- start and stop ------------------------------------------------------------------------

    def start(self) -> None:
        """Start the daemon, connect, build the simulator and the loop, start the loop."""
        from dataclasses import replace

        from roger_daemon.config.settings import FSM_MODEL
        from roger_daemon.harness import Client, DaemonProcess, write_config
        from simulator.config import SimConfig
        from simulator.episodes import SoccerSim
        from simulator.experiment.procs import child_env, free_port

        self.out.mkdir(parents=True, exist_ok=True)
        port = self.s.daemon_port or free_port()
        cfg = write_config(
            self.out / "daemon.toml", port=port, workdir=self.out,
            daemon={"clock": self.s.loop.clock, "mode": "learn+predict", "seed": self.s.loop.seed,
                    "queue_size": 100_000},
            checkpoint={"on_shutdown": True}, recording={"enabled": True},
            learner=dict(self.s.learner), robots=({"id": "aibo", "model": FSM_MODEL},))
        self.daemon = DaemonProcess(cfg, args=["--fresh"], log=self.out / "daemon.log",
                                    env=child_env())
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self.daemon.wait_ready(120)
        self.client = Client(self.endpoint)
        self.client.wait_daemon(30)
        base = SimConfig(vision=self.s.vision)
        sim_cfg = replace(base, episode=replace(base.episode, time_limit=self.s.time_limit))
        self.sim = SoccerSim(sim_cfg)
        self.loop = TeachLoop(self.s.loop, self.sim, self.client, self.autonomy)
        self.loop.after_step = self._after_step
        self.loop.on_correction_end = self.load_transitions
        self._thread = threading.Thread(target=self._run_loop, name="teach-loop", daemon=True)
        self._thread.start()

    def _run_loop(self) -> None:
        assert self.loop is not None
        try:
            self.loop.run()
        except Exception:  # the page shows the loop stopped; the log says why
            log.exception("the teaching loop stopped")
            self.loop.counts["loop_errors"] += 1

    def close(self) -> dict[str, Any]:
        """Stop the loop, the take, the daemon (final checkpoint); the session's summary."""
        summary: dict[str, Any] = {}
        if self.loop is not None:
            self.loop.stop.set()
            if self._thread is not None:
                self._thread.join(30)
            summary = {"ticks": self.loop.tick, "episodes": self.loop.episode + 1,
                       "counts": dict(self.loop.counts), "outcomes": dict(self.loop.outcomes)}
        self._stop_take()
        if self.client is not None:
            self.client.close()
        if self.daemon is not None:
            code, _ = self.daemon.terminate(60)
            summary["daemon_exit"] = code
        if self.sim is not None:
            self.sim.close()
        summary["refused"] = dict(self.refused)
        summary["takes"] = list(self.takes)
        return summary

    # -- what the page asks --------------------------------------------------------------------

    def handle(self, req: PageInput) -> str:
        """Carry out one request that is not a command; a short answer for the page."""
        assert self.loop is not None
        if req.type in ("mode", "reset", "place_ball"):
            self.loop.request(req)
            if req.type == "mode" and req.mode in ("autonomous", "correct"):
                self.load_transitions()
            return f"{req.type} requested"
        if req.type == "record":
            return self._start_take() if req.on else self._stop_take()
        if req.type == "checkpoint":
            st = self._checkpoint_written()
            return (f"checkpoint {st.info.get('checkpoint')} at "
                    f"{st.info.get('checkpoint_updates')} pairs")
        return ""

    def _start_take(self) -> str:
        from simulator.experiment.procs import child_env, roger_argv

        if self._take is not None and self._take.poll() is None:
            return "already recording"
        takes = self.out / "takes"
        takes.mkdir(parents=True, exist_ok=True)
        self._take_log = open(self.out / "takes.log", "ab")
        self._take = subprocess.Popen(
            roger_argv("record", "--out", str(takes), "--robot", self.client.robot,
                       "--connect", self.endpoint, "--listen", "tcp/127.0.0.1:0"),
            stdout=self._take_log, stderr=subprocess.STDOUT, env=child_env())
        self.takes.append(str(takes))
        # "recording" only once the recorder has its file open: a take stopped sooner would
        # leave nothing (the recorder's start-up takes a second or more)
        before = set(takes.glob("*.mcap"))
        deadline = time.monotonic() + 20.0
        while (self._take.poll() is None and time.monotonic() < deadline
               and not set(takes.glob("*.mcap")) - before):
            time.sleep(0.05)
        if self._take.poll() is not None:
            return f"the recorder exited ({self._take.returncode}): see {self.out / 'takes.log'}"
        return f"recording into {takes}"

    def _stop_take(self) -> str:
        if self._take is None:
            return "not recording"
        self._take.send_signal(signal.SIGINT)
        try:
            self._take.wait(30)
        except subprocess.TimeoutExpired:
            self._take.kill()
            self._take.wait(10)
        self._take = None
        if self._take_log is not None:
            self._take_log.close()
        return "recording stopped"

    @property
    def recording(self) -> bool:
        """Whether a take is being recorded."""
        return self._take is not None and self._take.poll() is None

    def load_transitions(self) -> None:
        """Load the daemon's newest transitions, in the background (once at a time): a
        checkpoint once its queue is empty, then :meth:`Autonomy.load`."""
        if self.loop is None or not self.loop.counts["pairs_sent"]:
            return
        with self._load_lock:
            if self.autonomy.loading:
                self._load_again = True  # after the running one: it may miss the newest pairs
                return
            self.autonomy.loading = True
        threading.Thread(target=self._load_transitions, name="teach-transitions",
                         daemon=True).start()

    def _load_transitions(self) -> None:
        while True:
            try:
                st = self.client.wait_status(lambda s: s.queue_depth == 0, 120)
                st = self._checkpoint_written()
                self.autonomy.load(self.out / "checkpoints", int(st.info.get(
                    "checkpoint_updates", st.updates)), self.client.robot)
                self.autonomy.fitted["checkpoint"] = Path(str(st.info.get("checkpoint"))).name
                log.info("playing the transitions of %s (%s pairs)",
                         st.info.get("checkpoint"), st.info.get("checkpoint_updates"))
            except (TimeoutError, RuntimeError, ValueError, OSError) as exc:
                # the previous ones act on
                log.warning("loading the learned transitions failed: %s", exc)
            with self._load_lock:
                if not self._load_again:
                    self.autonomy.loading = False
                    return
                self._load_again = False

    def snapshot(self) -> dict[str, Any]:
        """The loop's newest state with the daemon's newest status and the session's own."""
        assert self.loop is not None
        snap = dict(self.loop.snapshot())
        if not snap:
            return snap
        st = self.client.statuses[-1].msg if self.client.statuses else None
        if st is not None:
            info = st.info
            snap["daemon"] = {"mode": st.mode, "updates": st.updates, "experts": st.experts,
                              "queue_depth": st.queue_depth, "dropped": st.dropped,
                              "pairs_teacher": info.get("pairs_teacher", 0),
                              "pairs_robot": info.get("pairs_robot", 0),
                              "corrections": info.get("corrections", 0),
                              "level": info.get("level", "?"),
                              "learn_ms_p99": info.get("learn_ms_p99", 0.0)}
        inbox = self.loop.inbox
        snap["latency_ms"] = {"received_p50": _pct(inbox.to_received, 50),
                              "received_p99": _pct(inbox.to_received, 99),
                              "applied_p50": _pct(inbox.to_applied, 50),
                              "applied_p99": _pct(inbox.to_applied, 99),
                              "n": len(inbox.to_applied)}
        snap["rates_hz"] = self._rates()
        snap["recording"] = self.recording
        return snap

    def _rates(self) -> dict[str, float]:
        """Predictions received from the daemon and the loop's ticks per second, over the last
        two seconds."""
        import time

        recent = len(self.client.predictions_since(time.monotonic_ns() - 2_000_000_000))
        assert self.loop is not None
        ticks = list(self.loop.tick_times)  # a copy (the loop's thread appends)
        t = time.monotonic()
        return {"predictions": round(recent / 2.0, 1),
                "ticks": round(sum(1 for v in ticks if t - v <= 2.0) / 2.0, 1)}

    def _checkpoint_written(self) -> Any:
        """Ask for a checkpoint; the status once it is on disk (RobotClient.checkpoint)."""
        return self.client.checkpoint(60)

    # -- the camera image ----------------------------------------------------------------------

    def _after_step(self) -> None:
        """In the loop's thread (pybullet's): render the camera image when one is due."""
        if not self.want_image.is_set():
            return
        self.want_image.clear()
        rgb = camera_rgb(self.sim)
        text = jpeg_base64(rgb)
        with self._image_lock:
            self._image = text

    def image(self) -> str:
        """The newest camera image (a JPEG data URL), and ask for the next one."""
        self.want_image.set()
        with self._image_lock:
            return self._image


def camera_rgb(sim: Any) -> np.ndarray:
    """The robot's head camera as an ``(H, W, 3)`` uint8 image: the rendered vision's own
    frame when it has one, else a render of the same view. The carpet has no colour of its
    own in the simulator (the vision only segments), so it is painted green here, and what
    the camera sees of no body grey."""
    from simulator.bullet import p

    cam = sim.cfg.camera
    rgb = getattr(sim.vision, "last_rgb", None)
    seg = getattr(sim.vision, "last_mask", None)
    if rgb is None or seg is None:
        eye, rot = sim.world.camera_pose()
        view = p.computeViewMatrix(eye.tolist(), (eye + rot[:, 0]).tolist(), rot[:, 2].tolist())
        proj = p.computeProjectionMatrixFOV(cam.vfov, cam.width / cam.height, cam.near, cam.far)
        out = p.getCameraImage(cam.width, cam.height, view, proj, renderer=p.ER_TINY_RENDERER,
                               shadow=0, physicsClientId=sim.world.client)
        rgb, seg = out[2], out[4]
    arr = np.array(rgb, dtype=np.uint8).reshape(cam.height, cam.width, -1)[:, :, :3]
    ids = np.asarray(seg, dtype=np.int64).reshape(cam.height, cam.width)
    empty = ids < 0
    arr[empty] = (200, 200, 205)
    arr[empty & _below_horizon(sim)] = (61, 139, 61)
    return arr


def _below_horizon(sim: Any) -> np.ndarray:
    """``(H, W)``: the pixels whose ray points down (to the carpet) from the head camera."""
    import math

    cam = sim.cfg.camera
    _, rot = sim.world.camera_pose()
    forward, left, up = rot[:, 0], rot[:, 1], rot[:, 2]
    tx = math.tan(math.radians(cam.hfov) / 2)
    ty = math.tan(math.radians(cam.vfov) / 2)
    a = -(2 * (np.arange(cam.width) + 0.5) / cam.width - 1) * tx  # to the left
    b = (1 - 2 * (np.arange(cam.height) + 0.5) / cam.height) * ty  # upwards
    dz = forward[2] + a[None, :] * left[2] + b[:, None] * up[2]
    below: np.ndarray = dz < 0
    return below


def jpeg_base64(rgb: np.ndarray) -> str:
    """``rgb`` as a ``data:image/jpeg;base64,...`` URL."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, "JPEG", quality=80)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _pct(values: Any, q: float) -> float | None:
    """The ``q``-th percentile of ``values`` (ms, rounded), ``None`` when empty."""
    data = list(values)
    return round(float(np.percentile(data, q)), 2) if data else None

"""The experiment's jobs: one job = a few ``roger`` processes on private ports.

A job is what deployment runs, in miniature: ``roger sim`` (lockstep), a controller (``roger
hcc`` as demonstrator or transitioner, or ``roger experiment dpa``), and where needed ``roger
daemon`` (predict mode, resumed from a checkpoint) or ``roger record``
(:mod:`simulator.experiment.procs` starts and stops them). Every job listens on its own free
loopback ports, multicast scouting is off in every process, and nothing connects to the
conventional port 7447 (another daemon may be running there). Each process writes its output
to a log file in the job's directory; a job that fails raises
:class:`~simulator.experiment.procs.JobError` with the tail of the logs.

Topology (explicit endpoints, no gossip needed): the daemon or recorder listens on port A, the
simulator listens on B and connects to A; the controller connects to A and B. The simulator
starts its first episode once ``--wait-peers`` peers are connected.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_daemon.atomic import write_json
from roger_daemon.harness import write_config
from simulator.controllers.transitioner import DEFAULT_RULE
from simulator.experiment.procs import (
    JobError,
    ProcessGroup,
    free_port,
    roger_argv,
)

__all__ = ["DPA_TRACE", "EpisodeJob", "JobResult", "load_finished", "run_job"]

#: the DPA controller's per-tick perceptions and commands in its job's directory
#: (``roger experiment dpa --trace``; :mod:`simulator.experiment.averaging` reads it)
DPA_TRACE = "dpa-trace.npz"


@dataclass(frozen=True)
class EpisodeJob:
    """Episodes of one controller from some locations, in one ``roger sim`` run.

    ``controller``: ``demo`` (HCC demonstrator, recorded with ``roger record``), ``hcc`` (the
    HCC itself), ``roger`` (daemon in predict mode + HCC transitioner) or ``dpa`` (daemon
    serving the unimap model + ``roger experiment dpa``).
    """

    controller: str
    locations: tuple[int, ...]
    attempts: int
    seed: int
    time_limit: float
    vision: str
    workdir: Path
    checkpoint_dir: Path | None = None  # roger/dpa: <dir>/aibo/ckpt-*.npz to resume from
    learner: Mapping[str, Any] = field(default_factory=dict)
    learner_seed: int = 0
    task_config: str | None = None
    model_digest: str = ""  # of the checkpoint resumed from (part of the job's identity)
    name: str = ""  # result key (e.g. "roger:1" for the model of the second learner seed)
    rule: str = DEFAULT_RULE  # the transitioner's rule (roger hcc --rule)
    demo_noise: float = 0.0  # demo: roger hcc --demo-noise (simulator/controllers/demo_noise.py)

    @property
    def key(self) -> str:
        """The controller key its episodes are reported under."""
        return self.name or self.controller

    @property
    def episodes(self) -> int:
        """Episodes this job runs (locations x attempts)."""
        return len(self.locations) * self.attempts

    @property
    def sim_log(self) -> Path:
        """The simulator's log file."""
        return self.workdir / "sim.log"

    def spec(self) -> dict[str, Any]:
        """The job's identity as JSON (what ``--resume`` compares)."""
        return {
            "controller": self.controller, "locations": list(self.locations),
            "attempts": self.attempts, "seed": self.seed, "time_limit": self.time_limit,
            "vision": self.vision, "learner": dict(self.learner),
            "learner_seed": self.learner_seed, "task_config": self.task_config,
            "model_digest": self.model_digest, "name": self.name,
            "rule": self.rule if self.controller == "roger" else "",
            **({"demo_noise": self.demo_noise} if self.demo_noise else {}),
        }

    def timeout_s(self) -> float:
        """Generous wall-clock bound for the simulator run (>= 20 ticks/s)."""
        ticks = self.episodes * self.time_limit * 30.0
        return 120.0 + ticks / 20.0


@dataclass
class JobResult:
    """What one job produced."""

    job: EpisodeJob
    episodes: list[dict[str, Any]]
    summary: dict[str, Any]
    controller_stats: dict[str, Any]
    mcap: list[Path]
    wall_s: float


def _sim_argv(job: EpisodeJob, listen: int, connect: int | None, peers: int) -> list[str]:
    argv = roger_argv(
        "sim",
        "--clock", "lockstep",
        "--listen", f"tcp/127.0.0.1:{listen}",
        "--connect", f"tcp/127.0.0.1:{connect}" if connect else "none",
        "--locations", ",".join(str(loc) for loc in job.locations),
        "--episodes-per-location", str(job.attempts),
        "--seed", str(job.seed),
        "--episode-duration", repr(float(job.time_limit)),
        "--vision", job.vision,
        "--results", str(job.workdir / "sim.json"),
        "--wait-peers", str(peers),
        "--wait-subscribers", "60",
    )
    if job.task_config:
        argv += ["--config", job.task_config]
    return argv


def _link_checkpoints(src: Path, dst: Path) -> None:
    """Give a job its own checkpoint directory (hard links, or copies across filesystems)."""
    for f in sorted(src.rglob("ckpt-*.npz")):
        target = dst / f.relative_to(src)
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(f, target)
        except OSError:
            shutil.copy2(f, target)


def load_finished(job: EpisodeJob) -> JobResult | None:
    """The result of an earlier run of exactly this job in its directory, if complete."""
    try:
        done = json.loads((job.workdir / "job.json").read_text())
        sim = json.loads((job.workdir / "sim.json").read_text())
    except (OSError, ValueError):
        return None
    if done.get("spec") != json.loads(json.dumps(job.spec())):
        return None
    if len(sim.get("episodes", [])) != job.episodes:
        return None
    mcap = [job.workdir / p for p in done.get("mcap", [])]
    if not all(p.is_file() for p in mcap) or (job.controller == "demo" and not mcap):
        return None
    try:
        ctl = json.loads((job.workdir / "controller.json").read_text())
    except (OSError, ValueError):
        ctl = {}
    return JobResult(job, sim["episodes"], sim["summary"], ctl, mcap, float(done["wall_s"]))


def _start_predict_daemon(group: ProcessGroup, job: EpisodeJob, port: int) -> None:
    """Start ``roger daemon`` in predict mode resumed from the job's trained model."""
    if job.checkpoint_dir is None:
        raise ValueError(f"controller {job.controller} needs a checkpoint_dir")
    ck = job.workdir / "checkpoints"
    if ck.exists():
        shutil.rmtree(ck)
    _link_checkpoints(job.checkpoint_dir, ck)
    learner = {k: v for k, v in job.learner.items() if v is not None}
    cfg = write_config(
        job.workdir / "daemon.toml",
        port=port,
        workdir=job.workdir,
        # predict mode: no learning to move off the loop, so no worker process hop
        daemon={"mode": "predict", "clock": "lockstep", "seed": job.learner_seed,
                "workers": "inline"},
        checkpoint={"dir": ck, "on_shutdown": False, "every_updates": 0, "every_s": 0.0},
        recording={"enabled": False},
        learner=learner,
        # the learner table is fully resolved (scaling included): no robot profile
        robots=({"id": "aibo", "model": "unimap" if job.controller == "dpa" else "roger",
                 "profile": "none"},),
    )
    group.start("daemon", roger_argv("daemon", "--config", str(cfg)))
    group.wait_for_log("daemon", " ready: ", 120)
    if "resumed from" not in group.log_text("daemon"):
        raise JobError("the daemon did not resume the trained model" + group.tails())


def _wait_sim(group: ProcessGroup, timeout: float) -> int:
    """Wait for the simulator; stop the daemon as soon as the controller has left.

    The controller exits on the simulator's final event (``--exit-when-done``), and the
    simulator lingers until every subscriber of its episode events has left
    (``simulator.sim_node``, at most 2 s); the daemon subscribes to them too, so stopping it
    then lets the simulator close at once instead of after the whole linger. A controller
    that fails ends the job at once.
    """
    sim = group.procs["sim"].popen
    ctl = group.procs["controller"].popen
    end = time.monotonic() + timeout
    while sim.poll() is None:
        code = ctl.poll()
        if code is not None and code != 0:
            raise JobError(f"controller exited with {code}" + group.tails())
        if code == 0 and "daemon" in group.procs and group.procs["daemon"].popen.poll() is None:
            group.stop("daemon")
        if time.monotonic() > end:
            raise JobError(f"sim still running after {timeout:.0f} s" + group.tails())
        time.sleep(0.02)
    return int(sim.returncode)


def _noise_args(job: EpisodeJob) -> list[str]:
    """``roger hcc``'s disturbance options for a demonstration job (none without noise)."""
    if not job.demo_noise:
        return []
    from simulator.controllers.demo_noise import location_seed

    return ["--demo-noise", repr(job.demo_noise),
            "--demo-noise-seed", str(location_seed(job.seed, job.locations[0]))]


def run_job(job: EpisodeJob) -> JobResult:
    """Run one job's processes to completion; return the simulator's and controller's JSON."""
    job.workdir.mkdir(parents=True, exist_ok=True)
    for stale in ("job.json", "sim.json", "controller.json", DPA_TRACE):
        (job.workdir / stale).unlink(missing_ok=True)
    if (job.workdir / "mcap").exists():
        shutil.rmtree(job.workdir / "mcap")
    t0 = time.monotonic()
    group = ProcessGroup(job.workdir)
    sim_port = free_port()
    aux_port: int | None = None
    mcap: list[Path] = []
    try:
        stats = str(job.workdir / "controller.json")
        if job.controller == "demo":
            aux_port = free_port()
            rec_dir = job.workdir / "mcap"
            group.start("record", roger_argv(
                "record", "--key", "roger/aibo/**", "--out", str(rec_dir),
                "--listen", f"tcp/127.0.0.1:{aux_port}", "--connect", "none",
            ))
            group.wait_for_log("record", "recording ", 60)
            controller = roger_argv("hcc", "--role", "demonstrator", *_noise_args(job))
            peers = 2
        elif job.controller == "hcc":
            controller = roger_argv("hcc", "--role", "demonstrator")
            peers = 1
        elif job.controller in ("roger", "dpa"):
            aux_port = free_port()
            _start_predict_daemon(group, job, aux_port)
            if job.controller == "roger":
                controller = roger_argv("hcc", "--role", "transitioner", "--rule", job.rule)
            else:
                controller = roger_argv("experiment", "dpa", "--trace",
                                        str(job.workdir / DPA_TRACE))
            peers = 2
        else:
            raise ValueError(f"unknown controller {job.controller!r}")
        connect = ["--connect", f"tcp/127.0.0.1:{sim_port}"]
        if aux_port:
            connect += ["--connect", f"tcp/127.0.0.1:{aux_port}"]
        extra = ["--config", job.task_config] if job.task_config and "hcc" in controller else []
        group.start("controller", [*controller, *connect, "--exit-when-done", "--idle-exit",
                                   "120", "--stats", stats, *extra])
        group.start("sim", _sim_argv(job, sim_port, aux_port, peers))
        code = _wait_sim(group, job.timeout_s())
        if code != 0:
            raise JobError(f"sim exited with {code}" + group.tails())
        group.wait("controller", 60)
        if "record" in group.procs:
            group.stop("record")
            mcap = sorted((job.workdir / "mcap").glob("*.mcap"))
            if not mcap:
                raise JobError("the recorder wrote no MCAP file" + group.tails())
        if "daemon" in group.procs:
            group.stop("daemon")
        sim = json.loads((job.workdir / "sim.json").read_text())
        try:
            ctl = json.loads(Path(stats).read_text())
        except (OSError, ValueError):
            ctl = {}
    finally:
        group.close()
    wall = round(time.monotonic() - t0, 3)  # as --resume reads it back: the same totals
    write_json(job.workdir / "job.json", {  # what --resume reads: written whole or not at all
        "spec": job.spec(), "wall_s": wall,
        "mcap": [str(p.relative_to(job.workdir)) for p in mcap],
    })
    return JobResult(job, sim["episodes"], sim["summary"], ctl, mcap, wall)

"""Your own robot: teach a 6-D -> 2-D robot through a real ROGER daemon (runs as pasted).

The robot here is made up: a small arm that reads four joint angles, the load in its gripper
and a clock (6 perception entries) and commands two joint velocities (2 action entries). Its
demonstrator does one of two things: with nothing in the gripper it reaches (the velocities
pull joints 0 and 1 towards zero), with a load it carries (joints 2 and 3 drive).

What a user of ROGER writes for their own robot is all here:

1. a robot profile (TOML): the names and ranges of the vectors; the learner sees every range
   mapped onto [-1, 1], and ignores the clock (``configs/robots/aibo.toml`` is the AIBO's);
2. a daemon config whose ``[[robots]]`` table selects that profile;
3. ``roger daemon --config ...`` (here started by the script, on loopback);
4. the robot side, :class:`roger_daemon.client.RobotClient`: send the demonstrated action and
   the perception of every tick, get predictions back (mean, variance, the multimap).

    python docs/examples/your_robot.py
"""

import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from roger_daemon.client import RobotClient

PROFILE = """
name = "arm6"
description = "a made-up arm: 4 joints, gripper load, clock -> 2 joint velocities"
task = "reach for the object, then carry it"
rate_hz = 30.0
[perception]
names = ["q0", "q1", "q2", "q3", "load", "clock"]
ranges = [[-1.5, 1.5], [-1.5, 1.5], [-1.5, 1.5], [-1.5, 1.5], [0.0, 2.0], [0.0, 100.0]]
ignore = ["clock"]
[action]
names = ["v0", "v1"]
ranges = [[-1.0, 1.0], [-1.0, 1.0]]
"""


def daemon_config(port: int, work: Path) -> str:
    """A lockstep daemon on 127.0.0.1:<port> serving robot "arm" with the profile above."""
    return f"""
[daemon]
clock = "lockstep"          # answer every perception at once (a robot that waits for it)
[learner]
preset = "default"          # the recommended settings
[[robots]]
id = "arm"
profile = "{work / 'arm6.toml'}"
[zenoh]
listen = ["tcp/127.0.0.1:{port}"]
[checkpoint]
dir = "{work / 'checkpoints'}"
[recording]
dir = "{work / 'recordings'}"
"""


def demonstrator(x: np.ndarray) -> tuple[np.ndarray, str]:
    """The made-up teacher: reach without a load, carry with one."""
    if x[4] < 1.0:
        return np.array([-0.6 * x[0], -0.6 * x[1]]), "reach"
    return np.array([0.5 * np.tanh(2 * x[2]), 0.5 * np.sin(x[3])]), "carry"


class Arm:
    """The made-up robot: its joints wander smoothly; it picks up and puts down a load."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.q = np.zeros(4)
        self.load = 0.0

    def perception(self, tick: int) -> np.ndarray:
        """The next perception: joints, load, clock."""
        self.q = np.clip(self.q + self.rng.normal(0.0, 0.08, 4), -1.5, 1.5)
        if tick % 60 == 0:  # every two seconds it picks up or puts down the load
            self.load = 0.0 if self.load else 1.5
        return np.array([*self.q, self.load, tick / 30.0 % 100.0])


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> int:
    """Start a daemon, demonstrate 600 ticks (20 s at 30 Hz), then predict new ones."""
    arm = Arm(seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "arm6.toml").write_text(PROFILE)
        port = free_port()
        (work / "daemon.toml").write_text(daemon_config(port, work))
        daemon = subprocess.Popen([sys.executable, "-m", "roger_daemon", "daemon",
                                   "--config", str(work / "daemon.toml"), "--log-level",
                                   "warning"])
        try:
            with RobotClient(f"tcp/127.0.0.1:{port}", robot="arm", dims=(6, 2)) as robot:
                robot.wait_daemon(timeout=180)  # the first start compiles the kernels
                for tick in range(600):         # demonstration: action(t), perception(t)
                    x = arm.perception(tick)
                    y, label = demonstrator(x)
                    robot.send_action(tick, y, label=label)
                    pred = robot.predict(tick, x)
                print(f"demonstrated {pred.updates} pairs; "
                      f"{len(pred.multimap)} experts in the multimap")
                robot.set_mode("predict")       # the robot acts on its own now
                errors = []
                for tick in range(600, 660):
                    x = arm.perception(tick)
                    pred = robot.predict(tick, x)
                    want, label = demonstrator(x)
                    errors.append(float(np.abs(pred.mean - want).max()))
                    if tick < 603:
                        print(f"tick {tick} ({label}): predicted {np.round(pred.mean, 3)} "
                              f"(std {np.round(np.sqrt(pred.var), 3)}), teacher "
                              f"{np.round(want, 3)}; expert {pred.expert}")
                worst = float(np.median(errors))
                print(f"median of the largest error per tick over 60 new perceptions: "
                      f"{worst:.3f}")
        finally:
            daemon.terminate()                  # SIGTERM: checkpoint, close, exit 0
            code = daemon.wait(60)
    print(f"daemon exited with {code}")
    return 0 if code == 0 and worst < 0.1 else 1


if __name__ == "__main__":
    sys.exit(main())

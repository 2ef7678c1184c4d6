"""The secure deployment of ``configs/zenoh/secure/`` with real processes: a ``roger router``
with user/password authentication and the shipped ACL, a real ``roger daemon`` as an
authenticated client, and client sessions for the robot and operator roles.

Every allowed act is shown to work (so a refusal is not just a broken link), and every
forbidden act by a wrong-role or unauthenticated client is refused. The shipped files are used
as they are, except for the passwords (random per test) and the port.
"""

from __future__ import annotations

import json
import secrets
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from protocols import Action, Control, Perception, encode, keys
from roger_daemon.harness import DaemonProcess, free_port
from roger_daemon.router import exposed

zenoh = pytest.importorskip("zenoh")

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
SECURE = ROOT / "configs" / "zenoh" / "secure"
ROLES = ("daemon", "robot", "operator")


class Deployment:
    """Router + daemon of the secure configs, with per-test passwords."""

    def __init__(self, tmp: Path) -> None:
        import subprocess
        import sys

        self.tmp = tmp
        self.port = free_port()
        self.passwords = {r: secrets.token_hex(8) for r in ROLES}
        creds = tmp / "credentials.txt"
        creds.write_text("".join(f"roger-{r}:{p}\n" for r, p in self.passwords.items()))
        creds.chmod(0o600)
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.router_log = tmp / "router.log"
        self._log = open(self.router_log, "ab")  # closed in close()
        self.router = subprocess.Popen(
            [sys.executable, "-m", "roger_daemon", "router", "--config",
             str(SECURE / "router.json5"), "--listen", self.endpoint,
             "--set", f"transport/auth/usrpwd/dictionary_file={json.dumps(str(creds))}"],
            stdout=self._log, stderr=subprocess.STDOUT, cwd=ROOT,
        )
        self.daemon: DaemonProcess | None = None
        end = time.monotonic() + 60
        while "listening on" not in self.router_log.read_text():
            if self.router.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"router did not start:\n{self.router_log.read_text()}")
            time.sleep(0.05)

    def client_file(self, role: str, password: str | None = None) -> Path:
        """The shipped client config of ``role`` with this test's password and port."""
        text = (SECURE / f"{role}.json5").read_text()
        text = text.replace(f"change-me-{role}", password or self.passwords[role])
        text = text.replace("tcp/127.0.0.1:7447", self.endpoint)
        path = self.tmp / f"{role}-{secrets.token_hex(3)}.json5"
        path.write_text(text)
        return path

    def start_daemon(self) -> DaemonProcess:
        cfg = self.tmp / "daemon.toml"
        cfg.write_text(
            '[daemon]\nclock = "lockstep"\n'
            f'[zenoh]\nconfig_file = "{self.client_file("daemon")}"\nmode = "client"\n'
            f'connect = ["{self.endpoint}"]\n'
            f'[checkpoint]\ndir = "{self.tmp / "ckpt"}"\nevery_updates = 0\nevery_s = 0.0\n'
            f'[recording]\nenabled = false\n'
            '[[robots]]\nid = "aibo"\n'
        )
        self.daemon = DaemonProcess(cfg)
        self.daemon.wait_ready()
        return self.daemon

    def close(self) -> None:
        if self.daemon is not None:
            self.daemon.kill()
        if self.router.poll() is None:
            self.router.terminate()
            self.router.wait(15)
        self._log.close()


class Session:
    """A client (or peer) session with a subscriber on everything it may read."""

    def __init__(self, config: Path, *, mode: str | None = None, listen: str | None = None):
        cfg = zenoh.Config.from_file(str(config))
        if mode is not None:
            cfg.insert_json5("mode", json.dumps(mode))
        if listen is not None:
            cfg.insert_json5("listen/endpoints", json.dumps([listen]))
        self.s = zenoh.open(cfg)
        self.got: list[tuple[str, bytes]] = []  # what received() took from the channel
        # Zenoh's own channel (docs/zenoh-notes.md §3.3): the test only drains it
        self._sub = self.s.declare_subscriber("roger/**", zenoh.handlers.RingChannel(4096))

    def received(self) -> list[tuple[str, bytes]]:
        """Every sample so far: those already taken, then the channel drained."""
        while (sample := self._sub.try_recv()) is not None:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))
        return self.got

    def seen(self, key: str, payload: bytes) -> bool:
        return (key, payload) in self.received()

    def close(self) -> None:
        self.s.close()


def _arrives(sub: Session, key: str, payload: bytes, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if sub.seen(key, payload):
            return True
        time.sleep(0.02)
    return False


@pytest.fixture(scope="module")
def deployment(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    d = Deployment(tmp_path_factory.mktemp("secure"))  # one router for the module's tests
    try:
        yield d
    finally:
        d.close()


def _msg(kind: str, tick: int) -> bytes:
    if kind == "perception":
        return encode(Perception("aibo", tick, 0.0, x=np.zeros(23)))
    if kind == "action":
        return encode(Action("aibo", tick, 0.0, y=np.zeros(9)))
    return encode(Control("aibo", tick, 0.0, op="mode", mode="pause"))


def test_secure_configs_refuse_every_forbidden_act(deployment: Deployment) -> None:
    d = deployment
    robot = Session(d.client_file("robot"))
    operator = Session(d.client_file("operator"))
    watcher = Session(d.client_file("daemon"))  # sees what a daemon would receive
    opened = [robot, operator, watcher]
    try:
        time.sleep(0.5)
        # allowed: the control experiment, so that the refusals below mean something
        for who, kind in ((robot, "perception"), (robot, "action"), (operator, "control")):
            p = _msg(kind, 1)
            who.s.put(keys.key("aibo", kind), p)
            assert _arrives(watcher, keys.key("aibo", kind), p), (kind, "allowed but lost")
        # forbidden by role: each must not reach the other sessions
        forbidden = [
            (robot, "control"), (robot, "prediction"), (robot, "status"),
            (operator, "perception"), (operator, "action"), (operator, "prediction"),
            (watcher, "control"),  # a daemon identity may not send control either
        ]
        sent = []
        for who, kind in forbidden:
            p = b"forbidden-" + kind.encode() + secrets.token_bytes(4)
            who.s.put(keys.key("aibo", kind), p)
            sent.append((who, kind, p))
        _sentinels(opened, {robot: "perception", operator: "control", watcher: "prediction"})
        leaked = [(kind, o is watcher) for who, kind, p in sent for o in opened
                  if o is not who and o.seen(keys.key("aibo", kind), p)]
        assert leaked == []
        # only a daemon identity may declare roger/@daemon/*
        fake = robot.s.liveliness().declare_token(keys.daemon_liveliness("impostor"))
        real = watcher.s.liveliness().declare_token(keys.daemon_liveliness("genuine"))
        time.sleep(0.5)
        seen = {str(r.ok.key_expr) for r in operator.s.liveliness().get("roger/@daemon/*",
                                                                        timeout=2.0) if r.ok}
        assert keys.daemon_liveliness("genuine") in seen
        assert keys.daemon_liveliness("impostor") not in seen
        fake.undeclare()
        real.undeclare()
        # unauthenticated and wrong-password clients cannot even connect
        for bad in (d.client_file("robot", password="wrong"), _no_credentials(d)):
            with pytest.raises(zenoh.ZError):
                Session(bad)
        # a peer-mode session cannot get around the router: its own puts are judged by the
        # router's ACL, and no client accepts a direct link (clients never listen; the
        # router hands out no locators)
        rogue = Session(d.client_file("robot"), mode="peer",
                        listen=f"tcp/127.0.0.1:{free_port()}")
        opened.append(rogue)
        time.sleep(1.0)
        assert list(rogue.s.info.peers_zid()) == []
        p = b"peer-control" + secrets.token_bytes(4)
        rogue.s.put(keys.key("aibo", "control"), p)
        _sentinels([rogue, robot, operator, watcher], {rogue: "perception"})
        assert not any(o.seen(keys.key("aibo", "control"), p) for o in (robot, operator, watcher))
    finally:
        for s in opened:
            s.close()


def _sentinels(sessions: list[Session], allowed: dict[Session, str]) -> None:
    """Each sender publishes an allowed sample after its forbidden ones and every other
    session waits for it: samples of one sender keep their order through the router, so
    anything sent before a sentinel that was going to arrive has arrived."""
    for who, kind in allowed.items():
        p = b"sentinel" + secrets.token_bytes(4)
        who.s.put(keys.key("aibo", kind), p)
        for o in sessions:
            if o is not who:
                assert _arrives(o, keys.key("aibo", kind), p), (kind, "sentinel lost")


def _no_credentials(d: Deployment) -> Path:
    path = d.tmp / "anonymous.json5"
    path.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [d.endpoint]},
                                "scouting": {"multicast": {"enabled": False}}}))
    return path


def test_the_daemon_serves_authenticated_roles_and_ignores_a_robots_reset(
        deployment: Deployment) -> None:
    d = deployment
    d.start_daemon()
    robot = Session(d.client_file("robot"))
    operator = Session(d.client_file("operator"))
    try:
        time.sleep(0.5)
        robot.s.put(keys.action("aibo"), _msg("action", 0))
        robot.s.put(keys.perception("aibo"), _msg("perception", 0))
        assert _arrives_kind(robot, keys.prediction("aibo"), 10.0)  # the daemon answers
        robot.s.put(keys.control("aibo"), _msg("control", 0))  # a robot may not pause it
        time.sleep(1.0)
        robot.s.put(keys.perception("aibo"), _msg("perception", 1))
        assert _arrives_tick(robot, 1)  # still predicting: the robot's control was refused
        operator.s.put(keys.control("aibo"), _msg("control", 0))  # the operator may
        assert d.daemon is not None
        d.daemon.wait_for_log("mode learn+predict -> pause", 20)
    finally:
        robot.close()
        operator.close()


def _arrives_kind(sub: Session, key: str, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(k == key for k, _ in sub.received()):
            return True
        time.sleep(0.02)
    return False


def _arrives_tick(sub: Session, tick: int, timeout: float = 10.0) -> bool:
    from protocols import decode

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        preds = [p for k, p in sub.received() if k == keys.prediction("aibo")]
        if any(decode("prediction", p).tick == tick for p in preds):
            return True
        time.sleep(0.02)
    return False


def test_router_warns_only_when_exposed_without_acl() -> None:
    assert exposed(["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:7447"]) == []
    assert exposed(["tcp/0.0.0.0:7447", "tcp/127.0.0.1:1"]) == ["tcp/0.0.0.0:7447"]
    assert exposed(["tcp/[::]:7447"]) == ["tcp/[::]:7447"]


def test_the_shipped_daemon_table_is_a_valid_client_config(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from roger_daemon.config import load_config

    monkeypatch.chdir(ROOT)  # its paths are relative to the working directory
    cfg = load_config(SECURE / "daemon.toml")
    assert cfg.zenoh.mode == "client" and not cfg.zenoh.listen
    assert cfg.zenoh.config_file == Path("configs/zenoh/secure/daemon.json5")

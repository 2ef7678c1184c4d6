"""Issue 55, point 6: ``roger router`` refuses the shipped example passwords unless
``--insecure-example``, and warns about every listener other hosts reach without
authentication, not only without an ACL (docs/security.md). Real router processes."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from roger_daemon.harness import free_port
from roger_daemon.router import example_credentials, exposure_warning

pytest.importorskip("zenoh")

ROOT = Path(__file__).resolve().parents[1]
SECURE = ROOT / "configs" / "zenoh" / "secure"


def _router(*argv: str, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "ab") as out:  # the child has its own copy of the descriptor
        return subprocess.Popen([sys.executable, "-m", "roger_daemon", "router", *argv],
                                stdout=out, stderr=subprocess.STDOUT, cwd=ROOT)


def _until_listening(p: subprocess.Popen[bytes], log: Path) -> str:
    end = time.monotonic() + 60
    while "listening on" not in log.read_text():
        assert p.poll() is None and time.monotonic() < end, log.read_text()
        time.sleep(0.05)
    return log.read_text()


def _stop(p: subprocess.Popen[bytes]) -> None:
    p.terminate()
    assert p.wait(30) == 0


@pytest.mark.parametrize("copy", [False, True])
def test_the_example_credentials_are_refused(tmp_path: Path, copy: bool) -> None:
    argv = ["--config", str(SECURE / "router.json5"), "--listen",
            f"tcp/127.0.0.1:{free_port()}"]
    creds = SECURE / "credentials.example.txt"
    if copy:  # a copy under another name holds the same passwords
        creds = tmp_path / "mine.txt"
        creds.write_text((SECURE / "credentials.example.txt").read_text())
        argv += ["--set", f'transport/auth/usrpwd/dictionary_file="{creds}"']
    log = tmp_path / "router.log"
    p = _router(*argv, log=log)
    assert p.wait(60) == 2
    text = log.read_text()
    assert "example passwords" in text and str(creds.relative_to(ROOT) if not copy
                                               else creds) in text
    assert "roger-daemon" in text and "--insecure-example" in text
    assert "Traceback" not in text and "listening on" not in text


def test_insecure_example_starts_with_a_warning(tmp_path: Path) -> None:
    log = tmp_path / "router.log"
    p = _router("--config", str(SECURE / "router.json5"), "--listen",
                f"tcp/127.0.0.1:{free_port()}", "--insecure-example", log=log)
    try:
        text = _until_listening(p, log)
    finally:
        _stop(p)
    assert "running with the example passwords" in text


def test_own_credentials_are_taken(tmp_path: Path) -> None:
    creds = tmp_path / "creds.txt"
    creds.write_text("roger-daemon:s3cret-1\nroger-robot:s3cret-2\n")
    assert example_credentials(str(creds)) == []
    assert example_credentials(str(SECURE / "credentials.example.txt")) == [
        "roger-daemon", "roger-robot", "roger-operator"]
    assert example_credentials(None) == [] and example_credentials(str(tmp_path / "no")) == []


def test_a_public_listener_without_authentication_is_warned_about() -> None:
    public, local = ["tcp/0.0.0.0:7447"], ["tcp/127.0.0.1:7447"]
    acl_only = exposure_warning(public, acl=True, auth=False)
    assert "WITHOUT authentication" in acl_only and "as any role" in acl_only
    assert "WITHOUT authentication or access control" in exposure_warning(
        public, acl=False, auth=False)
    assert "WITHOUT access control" in exposure_warning(public, acl=False, auth=True)
    assert exposure_warning(public, acl=True, auth=True) == ""
    assert exposure_warning(local, acl=False, auth=False) == ""


def test_the_acl_only_router_on_a_public_address_warns(tmp_path: Path) -> None:
    """configs/zenoh/router-acl.json5 authenticates nobody: on 0.0.0.0 anyone may reset."""
    log = tmp_path / "router.log"
    p = _router("--config", str(ROOT / "configs" / "zenoh" / "router-acl.json5"), "--listen",
                f"tcp/0.0.0.0:{free_port()}", log=log)
    try:
        text = _until_listening(p, log)
    finally:
        _stop(p)
    assert "WITHOUT authentication:" in text and "access control on" in text

"""Files: one atomic writer, nothing deleted or overwritten that a command did not create,
and every command that reads a log rejects what is not one (clear message, non-zero exit).

Real files; the CLI runs in-process through ``roger_daemon.cli.main`` except where a real
subprocess is cheap and the point (``roger record`` to an unreachable endpoint).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protocols import Action, Perception, encode, keys
from roger_daemon.atomic import (
    OWNER_MARK,
    OutputDirError,
    atomic_write,
    owned_output_dir,
    write_bytes,
)
from roger_daemon.cli import main as roger
from roger_daemon.harness import free_port
from roger_daemon.recording import SessionRecorder

# -- the atomic writer -----------------------------------------------------------------------


def test_atomic_write_replaces_whole_or_not_at_all(tmp_path: Path) -> None:
    dst = tmp_path / "f.bin"
    write_bytes(dst, b"old")
    with pytest.raises(RuntimeError), atomic_write(dst) as f:
        f.write(b"half of the new")
        raise RuntimeError("killed mid-write")
    assert dst.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.bin"]  # no temporary left
    write_bytes(dst, b"new")
    assert dst.read_bytes() == b"new"


def test_atomic_write_without_overwrite_never_clobbers(tmp_path: Path) -> None:
    dst = tmp_path / "f.bin"
    write_bytes(dst, b"user's")
    with pytest.raises(FileExistsError):
        write_bytes(dst, b"mine", overwrite=False)
    assert dst.read_bytes() == b"user's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.bin"]


def test_one_atomic_writer_in_the_code() -> None:
    """Whole-file writes go through roger_daemon.atomic: no other os.replace/rename."""
    root = Path(__file__).resolve().parents[1]
    offenders = []
    for pkg in ("roger_daemon", "simulator", "protocols"):
        for py in (root / pkg).rglob("*.py"):
            text = py.read_text(encoding="utf-8")
            if py.name != "atomic.py" and (".replace(tmp" in text or "os.rename(" in text
                                           or "tmp.replace(" in text):
                offenders.append(str(py.relative_to(root)))
    assert offenders == [] or offenders == ["roger_daemon/recording/recover.py"], offenders


# -- output directories ------------------------------------------------------------------------


def test_owned_output_dir_keeps_what_it_did_not_create(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    with owned_output_dir(out, "demo") as d:
        (d / "summary.json").write_text("{}")
        (d / "recordings").mkdir()
    mark = json.loads((out / OWNER_MARK).read_text())
    assert mark == {"command": "demo", "created": ["recordings", "summary.json"]}
    (out / "my-notes.txt").write_text("the user's")
    with owned_output_dir(out, "demo") as d:
        assert not (d / "summary.json").exists()  # the earlier run's output is replaced
        (d / "summary.json").write_text("{}")
    assert (out / "my-notes.txt").read_text() == "the user's"


def test_owned_output_dir_refuses_a_foreign_directory(tmp_path: Path) -> None:
    out = tmp_path / "papers"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    with pytest.raises(OutputDirError, match="not empty.*--force"):
        with owned_output_dir(out, "demo"):
            pass
    assert (out / "thesis.tex").read_text() == "years of work"
    assert not (out / OWNER_MARK).exists()
    with owned_output_dir(out, "demo", force=True):
        pass
    assert not (out / "thesis.tex").exists()


def test_roger_demo_refuses_a_foreign_out_dir(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert roger(["demo", "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "x"


# -- commands that read logs ---------------------------------------------------------------


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("inputs")
    rec = SessionRecorder(d, robot="aibo", metadata={"robot": "aibo"})
    for t in range(20):
        rec.write(keys.perception("aibo"), encode(Perception("aibo", t, t / 30, x=np.zeros(23))),
                  log_time_ns=t + 1, publish_time_ns=t + 1, sequence=t)
        rec.write(keys.action("aibo"), encode(Action("aibo", t, t / 30, y=np.zeros(9))),
                  log_time_ns=t + 1, publish_time_ns=t + 1, sequence=t)
    rec.close()
    text = d / "notes.mcap"
    text.write_text("this is not a log\n")
    empty = d / "empty.mcap"
    empty.write_bytes(b"")
    return {"log": rec.path, "text": text, "empty": empty, "dir": d}


@pytest.mark.parametrize("argv", [
    ["log", "info", "{text}"],
    ["log", "info", "{empty}"],
    ["log", "info", "{dir}"],
    ["log", "export", "{text}", "--out", "{out}"],
    ["log", "recover", "{text}", "--out", "{out}"],
    ["replay", "{text}"],
    ["replay", "{dir}"],
])
def test_a_non_mcap_input_is_rejected(argv: list[str], files: dict[str, Path], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out.mcap"
    args = [a.format(out=out, **files) for a in argv]
    code = roger(args)
    err = capsys.readouterr().err
    assert code != 0
    assert ("not an MCAP file" in err) or ("is a directory" in err), err
    assert "Traceback" not in err
    assert not out.exists()  # nothing half-written


def test_outputs_are_not_overwritten_without_force(files: dict[str, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "exported.mcap"
    out.write_bytes(b"someone else's")
    assert roger(["log", "export", str(files["log"]), "--out", str(out)]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert out.read_bytes() == b"someone else's"
    assert roger(["log", "export", str(files["log"]), "--out", str(out), "--force"]) == 0
    assert out.read_bytes()[:5] == b"\x89MCAP"
    rec_out = tmp_path / "recovered.mcap"
    rec_out.write_bytes(b"precious")
    assert roger(["log", "recover", str(files["log"]), "--out", str(rec_out)]) == 2
    assert rec_out.read_bytes() == b"precious"


def test_recover_exit_code_says_whether_bytes_were_dropped(
        files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a killed writer whose last flush reached the disk: no footer, every byte readable
    rec = SessionRecorder(tmp_path / "killed", robot="aibo", metadata={"robot": "aibo"})
    for t in range(5):
        rec.write(keys.perception("aibo"), encode(Perception("aibo", t, 0.0, x=np.zeros(23))),
                  log_time_ns=t + 1, publish_time_ns=t + 1, sequence=t)
    rec.flush()
    killed = rec.path  # never closed
    assert roger(["log", "recover", str(killed), "--out", str(tmp_path / "a.mcap")]) == 3
    out = capsys.readouterr().out
    assert "no footer (its writer was killed" in out and "every byte on disk" in out
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(killed.read_bytes() + b"\x05" + bytes(40))  # a torn record at the end
    assert roger(["log", "recover", str(torn), "--out", str(tmp_path / "b.mcap")]) == 3
    assert "dropped 41 of" in capsys.readouterr().out
    assert roger(["log", "recover", str(files["log"]), "--out", str(tmp_path / "c.mcap")]) == 0


def test_replay_of_a_robot_absent_from_the_log_fails(files: dict[str, Path],
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    for extra in ([], ["--publish", "--connect", "none", "--listen", "none"]):
        assert roger(["replay", str(files["log"]), "--robot", "spot", *extra]) == 2
        err = capsys.readouterr().err
        assert "'spot' has no message" in err and "['aibo']" in err


def test_record_into_a_file_is_an_argument_error(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "notes.txt"
    out.write_text("mine")
    assert roger(["record", "--out", str(out), "--connect", "none"]) == 2
    assert "is not a directory" in capsys.readouterr().err
    assert out.read_text() == "mine"


@pytest.mark.integration
def test_record_to_an_unreachable_endpoint_fails_and_writes_nothing(tmp_path: Path) -> None:
    port = free_port()  # nobody listens there
    out = tmp_path / "rec"
    proc = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "record", "--out", str(out), "--connect",
         f"tcp/127.0.0.1:{port}", "--listen", "none", "--connect-timeout", "1"],
        capture_output=True, text=True, timeout=60, env={**os.environ, "RUST_LOG": "error"})
    assert proc.returncode == 1, proc.stderr
    assert f"cannot reach tcp/127.0.0.1:{port}" in proc.stderr and "nothing done" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()

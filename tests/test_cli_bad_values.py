"""Issue 55, point 5: bad command-line and config values are refused naming the value (exit
2, no traceback) and leave nothing behind; a cut-short log exports nothing; an input that
overflows the learner's scaling is refused in words, not with numpy's warnings. Each test
failed before its fix (docs/cli.md)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from cli_testing import Ran, in_process

from roger_daemon.cli import main as roger

ROOT = Path(__file__).resolve().parents[1]
SESSION = ROOT / "tests" / "data" / "sessions" / "sim-loc7-seed0.mcap"


@pytest.fixture
def run(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
        ) -> Iterator[Callable[..., Ran]]:
    """``roger ARGV`` in this process (tests/cli_testing.py)."""
    with in_process(capsys, monkeypatch) as run:
        yield run


def _usage_error(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """stderr of ``roger ARGV``, which must exit 2 without a traceback."""
    with pytest.raises(SystemExit) as exc:
        roger(list(argv))
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def test_save_checkpoint_into_a_file_exits_2_and_leaves_it(tmp_path: Path,
                                                          run: Callable[..., Ran]) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    for target in (notes, notes / "sub"):
        p = run("replay", str(SESSION), "--save-checkpoint", str(target), "--no-progress",
                cwd=tmp_path)
        assert p.returncode == 2, p.stderr
        assert "Traceback" not in p.stderr
        assert "--save-checkpoint must be a directory" in p.stderr and str(target) in p.stderr
    assert notes.read_text() == "my notes\n"
    assert sorted(tmp_path.iterdir()) == [notes]


@pytest.mark.parametrize("content", [b"my notes\n", b"", b"\x93NUMPY"])
def test_a_checkpoint_that_is_no_archive_is_named(tmp_path: Path, content: bytes,
                                                  run: Callable[..., Ran]) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_bytes(content)
    p = run("replay", str(SESSION), "--checkpoint", str(notes), "--no-progress", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr and "allow_pickle" not in p.stderr
    assert f"checkpoint {notes}" in p.stderr
    missing = tmp_path / "gone.npz"
    p = run("replay", str(SESSION), "--checkpoint", str(missing), "--no-progress", cwd=tmp_path)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert f"checkpoint {missing}: no such file" in p.stderr


def test_an_archive_of_no_model_is_named() -> None:
    from roger_daemon.replay.checkpoint import load_checkpoint
    from roger_daemon.replay.result import ReplayError

    path = Path(pytest.importorskip("tempfile").mkdtemp()) / "plain.npz"
    np.savez(path, a=np.zeros(3))
    with pytest.raises(ReplayError, match=f"checkpoint {path} is neither a daemon checkpoint"):
        load_checkpoint(path)


@pytest.mark.parametrize("argv", [
    ("replay", str(SESSION), "--tolerance", "-1"),
    ("replay", str(SESSION), "--tolerance", "nan"),
    ("replay", str(SESSION), "--tolerance", "inf"),
    ("replay", str(SESSION), "--publish", "--speed", "-2"),
    ("replay", str(SESSION), "--publish", "--wait", "nan"),
    ("hcc", "--prediction-timeout", "-1"),
    ("hcc", "--idle-exit", "-5"),
    ("hcc", "--max-prediction-age", "-3"),
    ("play", "--checkpoint", "x", "--prediction-timeout", "-1"),
    ("play", "--checkpoint", "x", "--idle-exit", "nan"),
    ("play", "--checkpoint", "x", "--max-prediction-age", "-3"),
])
def test_negative_or_nan_values_are_usage_errors(capsys: pytest.CaptureFixture[str],
                                                 argv: tuple[str, ...]) -> None:
    if argv[0] in ("hcc", "play"):
        pytest.importorskip("simulator")
    err = _usage_error(capsys, *argv)
    assert f"{argv[-2]}: " in err and f"got {argv[-1]!r}" in err


def test_the_defaults_still_parse(capsys: pytest.CaptureFixture[str]) -> None:
    from roger_daemon.cli import COMMANDS, build_parser

    args = build_parser(COMMANDS, "roger", "replay").parse_args(
        ["replay", str(SESSION), "--tolerance", "0"])
    assert args.tolerance == 0.0 and args.speed == 1.0 and args.wait == 2.0


@pytest.mark.parametrize("override", ['recording.dir=""', 'checkpoint.dir=""',
                                      'recording.dir=" "'])
def test_an_empty_directory_in_the_config_is_refused(tmp_path: Path, override: str,
                                                     run: Callable[..., Ran]) -> None:
    p = run("daemon", "--check", "--set", override, cwd=tmp_path)
    assert p.returncode == 2, p.stdout + p.stderr
    key = override.split("=")[0]
    assert f"{key} must be a directory (a non-empty path)" in p.stderr
    assert "Traceback" not in p.stderr
    assert list(tmp_path.iterdir()) == []  # no runs/recordings made


def test_a_directory_in_the_config_is_still_taken(tmp_path: Path) -> None:
    from roger_daemon.config import load_config

    cfg = load_config(None, [f'recording.dir="{tmp_path}/rec"', 'checkpoint.dir="ck"'])
    assert cfg.recording.dir == tmp_path / "rec"
    assert cfg.checkpoint.dir == Path("ck").absolute()


def test_exporting_a_cut_short_head_fails_and_writes_nothing(tmp_path: Path,
                                                            run: Callable[..., Ran]) -> None:
    head = tmp_path / "head.mcap"
    head.write_bytes(SESSION.read_bytes()[:300])
    p = run("log", "export", str(head), cwd=tmp_path)
    assert p.returncode == 1, p.stdout + p.stderr
    assert "has no readable message to export" in p.stderr and str(head) in p.stderr
    assert "Traceback" not in p.stderr
    assert sorted(tmp_path.iterdir()) == [head]  # neither an empty export nor a temporary


def test_an_input_that_overflows_the_scaling_is_refused_without_warnings() -> None:
    """|y| = 1e308 is finite but (y - offset) / scale is not: refused in words. |x| = 1e308
    gets an answer (every gate's density underflows: the CRP prior decides, §6)."""
    from roger_daemon.config import load_config
    from roger_daemon.daemon.main import make_model

    robot = load_config(None).robots[0]  # the AIBO profile: scaled inputs and outputs
    model = make_model(robot)
    x, y = np.zeros(robot.x_dim), np.zeros(robot.y_dim)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any numpy RuntimeWarning fails the test
        for k in range(3):
            model.learn_one(x + 0.02 * k, y + 0.01 * k)
        for big in (1e308, -1e308):
            yy = y.copy()
            yy[0] = big
            with pytest.raises(ValueError, match="y scaled to model units overflows"):
                model.learn_one(x, yy)
            xx = x.copy()
            xx[0] = big
            with pytest.raises(ValueError):
                model.learn_one(xx, y)
            pred, table = model.predict_table(xx)
            assert np.isfinite(pred.gate_prob) and np.all(np.isfinite(pred.mean))
            assert table.gate_probs == [1.0]
    assert model.n_learned == 3

"""Command-line conventions: every option has help, --version, exit 2 for user errors."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Iterator

import pytest

from roger_daemon import __version__
from roger_daemon.cli import BENCHES, COMMANDS, build_parser, main


def walk(parser: argparse.ArgumentParser, path: str) -> Iterator[tuple[str, argparse.Action]]:
    """Every action of ``parser`` and of its subcommands, recursively, with the command path."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from walk(sub, f"{path} {name}")
        else:
            yield path, action


def all_actions() -> Iterator[tuple[str, argparse.Action]]:
    yield from walk(build_parser(COMMANDS, "roger", "*"), "roger")
    yield from walk(build_parser(BENCHES, "roger bench", "*"), "roger bench")


def test_every_option_and_argument_has_help() -> None:
    missing = [f"{path} {'/'.join(a.option_strings) or a.dest}"
               for path, a in all_actions()
               if not isinstance(a, argparse._HelpAction)
               and (a.help is None or not a.help.strip()) and a.help != argparse.SUPPRESS]
    assert missing == [], "options without --help text: " + ", ".join(missing)


def test_one_name_per_concept() -> None:
    """The same concept is spelled the same in every command (robot id, JSON output)."""
    for path, a in all_actions():
        for opt in a.option_strings:
            assert opt not in ("--robot-id", "--robot_id"), f"{path}: use --robot"
        if "--json" in a.option_strings:
            assert a.nargs == 0, f"{path}: --json is a flag everywhere (got a value option)"


def test_every_command_accepts_log_level() -> None:
    for table, prog in ((COMMANDS, "roger"), (BENCHES, "roger bench")):
        for name in table:
            parser = build_parser(table, prog, name)
            sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            opts = {o for a in sub.choices[name]._actions for o in a.option_strings}
            assert "--log-level" in opts, f"{prog} {name}"


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"roger {__version__}"


def test_bad_log_level_is_a_usage_error() -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--log-level", "loud", "list"])
    assert exc.value.code == 2


def test_user_error_exits_2_with_a_message_and_no_traceback(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["echo", "roger/a b/c//", "--timeout", "1"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "KEY must be a key expression" in err
    assert "'roger/a b/c//'" in err
    assert main(["bench", "learner", "--param", "partcles=5"]) == 2
    err = capsys.readouterr().err
    assert "unknown parameter(s) 'partcles'" in err and "particles" in err
    assert main(["bench", "learner", "--threads", "0"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "--threads must be an integer >= 1, got 0" in err


def test_closed_stdout_exits_quietly() -> None:
    """`roger ... | head`: the reader went away before the output was written."""
    p = subprocess.Popen([sys.executable, "-m", "roger_daemon", "config", "example", "daemon"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(60) == 141
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_ctrl_c_exits_130_without_a_traceback() -> None:
    """SIGINT while `roger hz` waits for messages (nothing publishes: it waits forever)."""
    import signal

    from roger_daemon.harness import free_port, interruptible_child

    with interruptible_child():  # also when the suite runs as a background job
        p = subprocess.Popen([sys.executable, "-m", "roger_daemon", "hz", "aibo/status",
                              "--connect", f"tcp/127.0.0.1:{free_port()}"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout is not None
        first = p.stdout.readline()  # the first report: it is inside its loop now
        assert "waiting for messages" in first
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err


def test_config_example_prints_the_shipped_file(capsys: pytest.CaptureFixture[str]) -> None:
    from pathlib import Path

    assert main(["config", "example", "systemd"]) == 0
    shipped = Path(__file__).parents[1] / "configs" / "systemd" / "roger-daemon.service"
    assert capsys.readouterr().out == shipped.read_text(encoding="utf-8")
    assert main(["config", "example", "nonsense"]) == 2
    assert "must be one of daemon" in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["bench", "fleet", "--robots", "0"], "--robots must be an integer >= 1, got 0"),
    (["bench", "fleet", "--seconds", "-1"], "--duration must be a number > 0, got -1.0"),
    (["bench", "fleet", "--duration", "-1"], "--duration must be a number > 0, got -1.0"),
    (["bench", "soak", "--duration", "0"], "--duration must be a number > 0, got 0.0"),
    (["bench", "soak", "--minutes", "0"], "--minutes must be a number > 0, got 0.0"),
    (["bench", "soak", "--interval", "0"], "--interval must be a number > 0, got 0.0"),
])
def test_benchmark_ranges_are_usage_errors_naming_the_value(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Out-of-range benchmark options stop before anything starts: exit 2, the option, the
    expected form and the value given."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_one_word_for_a_duration_and_out_is_a_directory() -> None:
    """Issue 56: ``--duration`` / ``--episode-duration`` / ``--PHASE-duration`` in seconds
    (the old ``--seconds``, ``--minutes``, ``--time-limit`` and any option named in a unit
    only as deprecated aliases, said so in --help), and every ``--out`` of a roger command is
    a directory."""
    old = {"--seconds", "--minutes", "--time-limit"}
    unit = re.compile(r"-(seconds|minutes|hours|s|ms)$")  # --warmup-minutes, --rotate-s
    for path, a in all_actions():
        opts = a.option_strings
        if old & set(opts) or any(unit.search(o) for o in opts):
            assert "deprecated" in (a.help or ""), f"{path} {opts}: say so in --help"
        if "--out" in opts:
            assert a.metavar == "DIR", f"{path} --out is a {a.metavar}, not a directory"


def test_the_log_file_is_positional_everywhere() -> None:
    """log info|recover|export, replay and view take the log as their first argument."""
    parser = build_parser(COMMANDS, "roger", "*")
    for argv in (["log", "info", "F.mcap"], ["log", "recover", "F.mcap"],
                 ["log", "export", "F.mcap"], ["replay", "F.mcap"], ["view", "F.mcap"]):
        values = vars(parser.parse_args(argv)).values()
        flat = [w for v in values for w in (v if isinstance(v, list) else [v])]
        assert "F.mcap" in {str(v) for v in flat}, argv

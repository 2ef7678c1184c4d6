"""One learner interface in the daemon (issue 58): the loop calls ``Learners`` only, whichever
host has the models, so it has no mode branches."""

from __future__ import annotations

import ast
import inspect
import re
from pathlib import Path

import pytest

from roger_daemon.daemon.learner_host import InlineLearners, Learners
from roger_daemon.daemon.learners import ProcessLearners

DAEMON = Path(__file__).resolve().parents[1] / "roger_daemon" / "daemon"


def _protocol_methods() -> set[str]:
    return {name for name, _ in inspect.getmembers(Learners, inspect.isfunction)
            if not name.startswith("_")} | {"prepares", "in_process"}


@pytest.mark.parametrize("host", [InlineLearners, ProcessLearners])
def test_both_hosts_have_every_method_of_the_interface(host: type) -> None:
    """Each host implements the whole interface, with the protocol's parameters."""
    for name in sorted(_protocol_methods()):
        assert hasattr(host, name), f"{host.__name__} lacks {name}"
        if name in ("prepares", "in_process"):
            continue
        want = list(inspect.signature(getattr(Learners, name)).parameters)
        got = list(inspect.signature(getattr(host, name)).parameters)
        assert got[:len(want)] == want, (host.__name__, name, got, want)
    assert InlineLearners.prepares is False and ProcessLearners.prepares is True
    assert InlineLearners.in_process is True and ProcessLearners.in_process is False


def test_the_daemon_never_asks_which_host_it_has() -> None:
    """No branch on the mode: no ``learners is (not) None`` anywhere in the daemon package,
    and no free function of the service reaches for the inline learning state."""
    hits = []
    for path in sorted(DAEMON.rglob("*.py")):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"learners is (not )?None", line):
                hits.append(f"{path.relative_to(DAEMON)}:{n}: {line.strip()}")
    assert not hits, "\n".join(hits)
    loop = (DAEMON / "service" / "loop.py").read_text()
    for gone in ("_learn_once", "_can_learn", "_learned_since_tick", "_learn_est_ns"):
        assert gone not in loop, gone


def _takes_the_service(source: str) -> list[str]:
    """The top-level functions of ``source`` whose first parameter is annotated ``Service``."""
    hits = []
    for node in ast.parse(source).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            params = [*node.args.posonlyargs, *node.args.args]
            note = params[0].annotation if params else None
            if note is not None and ast.unparse(note).strip("'\"").endswith("Service"):
                hits.append(node.name)
    return hits


def test_no_service_part_is_a_free_function_of_the_service() -> None:
    """The service's parts are objects built with what they need (issue 58): no module of the
    service but its loop has a free function that is handed the whole ``Service``."""
    assert _takes_the_service("def f(svc: Service, now: int) -> None: ...") == ["f"]
    assert _takes_the_service("def f(svc: 'loop.Service') -> None: ...") == ["f"]
    assert _takes_the_service("def f(rt: RobotRuntime, svc: Service) -> None: ...") == []
    hits = [f"{path.name}: {name}" for path in sorted((DAEMON / "service").glob("*.py"))
            if path.name != "loop.py"
            for name in _takes_the_service(path.read_text())]
    assert not hits, hits


def test_inline_learners_refuse_to_answer_before_attach() -> None:
    """A host used before the service attached it says so (instead of an AttributeError)."""
    with pytest.raises(RuntimeError, match="before attach"):
        InlineLearners({}).snapshot(None, "requested", sync=True)  # type: ignore[arg-type]

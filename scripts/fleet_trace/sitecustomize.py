"""Loaded by every Python process started with this directory on ``PYTHONPATH``: with
``ROGER_FLEET_TRACE_DIR`` set, a ``roger daemon`` process or one of its learner workers wraps
the spans of :mod:`fleet_spans` (plus each prediction's send, the worker's requests and the
publication) and writes what it recorded to ``<dir>/<d|w>_<pid>.json`` at exit. Any other
process is left alone. Used by ``scripts/fleet_trace.py``; not part of the package."""

from __future__ import annotations

import atexit
import builtins
import gc
import importlib
import json
import os
import sys
import time
from typing import Any

_DIR = os.environ.get("ROGER_FLEET_TRACE_DIR", "")
try:
    with open("/proc/self/cmdline", "rb") as _f:
        _CMD = _f.read().split(b"\0")
except OSError:
    _CMD = []
_WORKER = b"roger_daemon.daemon.worker" in _CMD
_DAEMON = not _WORKER and b"daemon" in _CMD and b"--config" in _CMD
EVENTS: list[tuple[str, str, int, int, int]] = []


def _wrap(owner: Any, name: str, label: str) -> None:
    fn = getattr(owner, name)
    clock = time.monotonic_ns

    def timed(*args: Any, **kwargs: Any) -> Any:
        start = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            EVENTS.append((label, "", -1, start, clock()))

    setattr(owner, name, timed)


def _resolve(module: str, path: str) -> tuple[Any, str]:
    owner: Any = sys.modules[module] if module == "__main__" else importlib.import_module(module)
    *parents, name = path.split(".")
    for p in parents:
        owner = getattr(owner, p)
    return owner, name


def _install_daemon() -> None:
    import fleet_spans

    from roger_daemon.daemon import learners
    from roger_daemon.daemon.service import answers

    for module, path, label in fleet_spans.DAEMON:
        _wrap(*_resolve(module, path), label)
    send = learners.ProcessLearners._send_predict

    def send_predict(self: Any, s: Any, perc: Any, recv_ns: int, *, prepared: bool) -> Any:
        EVENTS.append(("sent", s.rt.robot, perc.tick, recv_ns, time.monotonic_ns()))
        return send(self, s, perc, recv_ns, prepared=prepared)

    learners.ProcessLearners._send_predict = send_predict  # type: ignore[method-assign]
    publish = answers._worker_prediction

    def worker_prediction(svc: Any, rt: Any, reply: Any, perc: Any, recv_ns: int) -> Any:
        start = time.monotonic_ns()
        out = publish(svc, rt, reply, perc, recv_ns)
        EVENTS.append(("published", rt.robot, perc.tick, start, time.monotonic_ns()))
        return out

    answers._worker_prediction = worker_prediction


def _install_worker() -> None:
    import fleet_spans

    for module, path, label in fleet_spans.WORKER:
        _wrap(*_resolve(module, path), label)
    cls = sys.modules["__main__"]._Worker
    handle = cls.handle

    def timed_handle(self: Any, req: dict[str, Any]) -> Any:
        start = time.monotonic_ns()
        out = handle(self, req)
        robot = getattr(self.rt, "robot", "")
        EVENTS.append((f"worker_{req.get('op')}", robot, int(req.get("tick", -1) or -1), start,
                       time.monotonic_ns()))
        return out

    cls.handle = timed_handle


def _ready() -> bool:
    if _WORKER:
        return hasattr(sys.modules.get("__main__"), "_Worker")
    m = sys.modules
    return (hasattr(m.get("roger_daemon.daemon.service.loop"), "Service")
            and hasattr(m.get("roger_daemon.daemon.learners"), "ProcessLearners")
            and hasattr(m.get("roger_daemon.daemon.service.answers"), "_worker_prediction"))


if _DIR and (_DAEMON or _WORKER):
    _import = builtins.__import__
    _installed = [False]
    _gc_start = [0]

    def _on_gc(phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            _gc_start[0] = time.monotonic_ns()
        else:
            EVENTS.append(("collection", "", int(info.get("generation", -1)), _gc_start[0],
                           time.monotonic_ns()))

    def _hook(name: str, *args: Any, **kwargs: Any) -> Any:
        module = _import(name, *args, **kwargs)
        if not _installed[0] and _ready():
            _installed[0] = True
            builtins.__import__ = _import
            (_install_worker if _WORKER else _install_daemon)()
        return module

    builtins.__import__ = _hook
    gc.callbacks.append(_on_gc)

    def _dump() -> None:
        kind = "w" if _WORKER else "d"
        with open(os.path.join(_DIR, f"{kind}_{os.getpid()}.json"), "w", encoding="utf-8") as f:
            json.dump(EVENTS, f)

    atexit.register(_dump)

"""A learner worker process: the models of one or more robots, driven over a pipe
(``[daemon] workers``, ``worker_processes``).

``python -m roger_daemon.daemon.worker`` reads requests on stdin and answers each with exactly
one reply on stdout, in order. Every request but ``stop`` names the ``robot`` whose model it
is for (the ``load`` of that robot gives it one). Frames are ``u32 length (little endian) |
msgpack map``; arrays travel as ``{"t": dtype, "s": shape, "b": bytes}`` (numeric and
fixed-width unicode dtypes only; never pickle). Log lines go to stderr (the daemon's log).
The worker pins BLAS to one thread (:func:`roger_daemon.blas.pin_blas_threads`), so its
floats are the in-process model's, bit for bit.

Requests (``op``) and replies:

- ``load``: ``robot``, ``x_dim``, ``y_dim``, ``model`` (``roger`` | ``unimap``), ``seed``,
  ``params`` (the learner parameter mapping), ``state`` (a model ``state_dict`` or nil for a
  fresh model), ``codes`` (label codes of the learned pairs) -> ``n``, ``experts``,
  ``kernels`` (the learner's compiled kernel signatures: the worker warms them up on load, so
  no step compiles or loads one from numba's cache), ``threads`` (its learner's threads,
  ``--threads``);
- ``learn``: ``x``, ``y`` (float64 bytes), ``code``, ``tick``, ``vocab`` (only when it grew)
  -> ``ok``, ``ms``, ``n``, ``experts`` (``ok`` false: the learner rejected the pair, the
  model is unchanged); when no request waits after it, the worker counts the labels of what
  it learned (``_Worker.idle``), so the next prediction need not, and collects any garbage
  due (:mod:`roger_daemon.daemon.gc_policy`; after ``load`` collections wait for these
  moments);
- ``predict``: ``x``, ``tick``, ``t``, ``vocab`` (only when it grew) -> ``ok``, ``pred`` (an
  encoded ``Prediction``: mean, variance, multimap with majority labels, ``updates``), ``ms``;
- ``fresh``: replace the model by a fresh one (``reset``) -> ``n``, ``experts``;
- ``snapshot``: -> ``state`` (the model's ``state_dict``), ``n``;
- ``stop``: -> ``{}``, then the process exits.

``--nice N`` (the daemon's ``[daemon] worker_nice``) lowers the worker's CPU priority by
``N`` at start (``os.nice``): serving predictions goes before learning (docs/fleet.md).

An unexpected error answers ``fatal`` (the traceback text) and the worker exits 1. End of
input (the daemon died) ends the worker too. The daemon's side is
:mod:`roger_daemon.daemon.learners`.
"""

from __future__ import annotations

import argparse
import logging
import os
import select
import struct
import sys
import traceback
from collections.abc import Mapping
from typing import IO, Any

import msgpack
import numpy as np

from protocols.packing import packb

__all__ = ["FrameReader", "pack_arrays", "read_frame", "unpack_arrays", "write_frame"]

log = logging.getLogger(__name__)

_LEN = struct.Struct("<I")
_KINDS = frozenset("biufU")  # bool, int, uint, float, fixed-width unicode: nothing else
MAX_FRAME = 1 << 30


def pack_arrays(arrays: Mapping[str, np.ndarray]) -> dict[str, dict[str, Any]]:
    """Named arrays as msgpack-ready maps (dtype string, shape, raw bytes)."""
    out = {}
    for name, value in arrays.items():
        a = np.asarray(value)  # tobytes() is C order; ascontiguousarray would make 0-d 1-d
        if a.dtype.kind not in _KINDS:
            raise TypeError(f"array {name} has dtype {a.dtype}; only numeric and unicode")
        out[name] = {"t": a.dtype.str, "s": list(a.shape), "b": a.tobytes()}
    return out


def unpack_arrays(packed: Any, *, copy: bool = True) -> dict[str, np.ndarray]:
    """The inverse of :func:`pack_arrays`; raises ``ValueError`` on anything else.

    ``copy=False`` returns read-only views of the frame's bytes (one copy less of a model
    state that is only written to disk)."""
    if not isinstance(packed, dict):
        raise ValueError("arrays must be a map")
    out = {}
    for name, m in packed.items():
        if not isinstance(name, str) or not isinstance(m, dict):
            raise ValueError("bad array entry")
        dt = np.dtype(str(m.get("t")))
        shape = m.get("s")
        data = m.get("b")
        if dt.kind not in _KINDS or not isinstance(data, bytes) or not isinstance(shape, list) \
                or not all(isinstance(d, int) and d >= 0 for d in shape):
            raise ValueError(f"bad array {name}")
        if int(np.prod(shape, dtype=np.int64)) * dt.itemsize != len(data):
            raise ValueError(f"array {name}: {len(data)} bytes do not match {dt} {shape}")
        a = np.frombuffer(data, dtype=dt).reshape(shape)
        out[name] = a.copy() if copy else a
    return out


def write_frame(f: IO[bytes], msg: Mapping[str, Any]) -> None:
    """One length-prefixed msgpack frame, flushed."""
    payload = packb(msg)
    f.write(_LEN.pack(len(payload)) + payload)
    f.flush()


def _read_exact(f: IO[bytes], n: int) -> bytearray | None:
    buf = bytearray(n)  # read in place: a model state is not held twice
    view = memoryview(buf)
    pos = 0
    while pos < n:
        got = f.readinto(view[pos:])  # type: ignore[attr-defined]
        if not got:
            return None
        pos += got
    return buf


def read_frame(f: IO[bytes]) -> dict[str, Any] | None:
    """The next frame's map; ``None`` at end of input. A bad frame raises ``ValueError``."""
    head = _read_exact(f, _LEN.size)
    if head is None:
        return None
    (length,) = _LEN.unpack(head)
    if length > MAX_FRAME:
        raise ValueError(f"frame of {length} bytes")
    payload = _read_exact(f, length)
    if payload is None:
        return None
    return _frame_map(payload)


def _frame_map(payload: bytearray) -> dict[str, Any]:
    try:
        msg = msgpack.unpackb(payload, raw=False)
    except (msgpack.UnpackException, ValueError) as exc:  # OutOfData is not a ValueError
        raise ValueError(f"bad frame: {type(exc).__name__}: {exc}") from None
    if not isinstance(msg, dict):
        raise ValueError("frame is not a map")
    return msg


class FrameReader:
    """Reads frames from a non-blocking pipe as its bytes arrive (the daemon's side).

    ``raw`` is the pipe's unbuffered file (``FileIO``, ``O_NONBLOCK``). :meth:`read` takes
    whatever the pipe holds now and returns the frames completed by it; a frame is read in
    place into a buffer of its size, so a model state is not held twice. ``eof`` is set at
    end of input. A bad frame raises ``ValueError``, as :func:`read_frame` does.
    """

    def __init__(self, raw: Any) -> None:
        self._raw = raw
        self._head = bytearray(_LEN.size)
        self._payload: bytearray | None = None
        self._pos = 0
        self.eof = False

    def read(self) -> list[dict[str, Any]]:
        """The frames completed by what the pipe holds now (none when it is empty)."""
        frames: list[dict[str, Any]] = []
        while not self.eof:
            target = self._head if self._payload is None else self._payload
            if self._pos < len(target):
                got = self._raw.readinto(memoryview(target)[self._pos:])
                if got is None:  # nothing more for now
                    break
                if got == 0:
                    self.eof = True
                    break
                self._pos += got
                if self._pos < len(target):
                    continue
            if self._payload is None:
                (length,) = _LEN.unpack(self._head)
                if length > MAX_FRAME:
                    raise ValueError(f"frame of {length} bytes")
                self._payload, self._pos = bytearray(length), 0
            else:
                payload, self._payload, self._pos = self._payload, None, 0
                frames.append(_frame_map(payload))
        return frames


def _vec(b: Any, n: int) -> np.ndarray:
    a = np.frombuffer(b, dtype="<f8")
    if a.size != n:
        raise ValueError(f"expected {n} floats, got {a.size}")
    return a.astype(np.float64)


class _Worker:
    """The model of one robot and the daemon bookkeeping that labels its experts."""

    def __init__(self) -> None:
        self.rt: Any = None
        self.idle_failed = False  # counting labels ahead failed once (logged once)

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op = req.get("op")
        if op == "load":
            return self._load(req)
        if self.rt is None:
            raise RuntimeError(f"{op!r} before 'load'")
        rt = self.rt
        if op == "learn":
            return self._learn(req)
        if op == "predict":
            return self._predict(req)
        if op == "fresh":
            rt.reset()
            return {"n": rt.updates, "experts": int(rt.model.n_experts)}
        if op == "snapshot":
            return {"state": pack_arrays(rt.model.state_dict()), "n": rt.updates}
        if op == "stop":
            return {}
        raise ValueError(f"unknown op {op!r}")

    def _load(self, req: dict[str, Any]) -> dict[str, Any]:
        from protocols.messages import Dims
        from roger_daemon.config.models import build_model, load_model
        from roger_daemon.daemon.robot import RobotRuntime
        from roger_daemon.learner import RogerParams
        from roger_daemon.learner.engine.jit import compiled_signatures, threads, warm_up

        warm_up()  # the compiled kernels now, not inside this robot's first steps
        dims = Dims(int(req["x_dim"]), int(req["y_dim"]))
        kind, seed = str(req["model"]), int(req["seed"])
        params = RogerParams.from_mapping(req["params"])

        def fresh() -> Any:
            return build_model(kind, dims.x, dims.y, params, seed)

        state = req.get("state")
        model = fresh() if state is None else load_model(unpack_arrays(state))
        rt = RobotRuntime(str(req["robot"]), dims, model, fresh)
        codes = unpack_arrays(req["codes"])["codes"] if req.get("codes") else np.zeros(0)
        for c in codes.astype(np.int64):
            rt._append_code(int(c))
        self.rt = rt
        return {"n": rt.updates, "experts": int(rt.model.n_experts),
                "kernels": compiled_signatures("roger_daemon.learner"), "threads": threads()}

    def _vocab(self, req: dict[str, Any]) -> None:
        """The daemon's label vocabulary, when the request carries it (the codes index it)."""
        if "vocab" not in req:
            return
        vocab = [str(v) for v in req["vocab"]]
        if vocab != self.rt.vocab:
            self.rt.vocab = vocab
            self.rt._labels_cache = None

    def idle(self) -> None:
        """Nothing waits: count the labels of what was just learned now (cached per model
        generation), so the next prediction does not (~0.12 ms of its time, docs/fleet.md)."""
        if self.rt is not None and self.rt.model is not None:
            self.rt.expert_labels()

    def _learn(self, req: dict[str, Any]) -> dict[str, Any]:
        from roger_daemon.daemon.robot import Pair

        rt = self.rt
        self._vocab(req)
        x = _vec(req["x"], rt.dims.x)
        y = _vec(req["y"], rt.dims.y)
        rt.queue.append(Pair(x, y, int(req["code"]), int(req["tick"])))
        errors = rt.learn_errors
        ms = rt.learn_one()
        return {"ok": rt.learn_errors == errors, "ms": ms, "n": rt.updates,
                "experts": int(rt.model.n_experts)}

    def _predict(self, req: dict[str, Any]) -> dict[str, Any]:
        from protocols.messages import Perception

        rt = self.rt
        self._vocab(req)
        perc = Perception(rt.robot, int(req["tick"]), float(req["t"]),
                          x=_vec(req["x"], rt.dims.x))
        reply: dict[str, Any] = rt.answer(perc)
        return reply


def main(argv: list[str] | None = None) -> int:
    """The worker's loop: one reply per request, until ``stop`` or end of input."""
    logging.basicConfig(level="INFO", stream=sys.stderr,
                        format="%(levelname)s %(name)s (worker): %(message)s")
    from roger_daemon.blas import pin_blas_threads
    from roger_daemon.daemon.gc_policy import (
        Thresholds,
        collect_when_idle,
        freeze_survivors,
        hold_collections,
    )
    from roger_daemon.daemon.memory import limit_heap_growth
    from roger_daemon.learner.engine.jit import set_threads

    parser = argparse.ArgumentParser(prog="python -m roger_daemon.daemon.worker")
    parser.add_argument("--nice", type=int, default=0, choices=range(20), metavar="0..19")
    parser.add_argument("--threads", type=int, default=1, metavar="N",
                        help="the learner's threads, >= 1 (roger_daemon.learner.engine.jit)")
    args = parser.parse_args(argv)
    if args.threads < 1:
        parser.error(f"--threads must be an integer >= 1, got {args.threads}")
    if args.nice:
        os.nice(args.nice)
    pin_blas_threads(1)
    set_threads(args.threads)
    limit_heap_growth()
    # unbuffered input, so that select() tells whether the daemon sent another request
    stdin, stdout = getattr(sys.stdin.buffer, "raw", sys.stdin.buffer), sys.stdout.buffer
    workers: dict[str, _Worker] = {}  # robot id -> its model and bookkeeping
    thresholds: Thresholds | None = None
    while True:
        req = read_frame(stdin)
        if req is None:
            return 0
        op = req.get("op")
        if op == "stop":
            write_frame(stdout, {})
            return 0
        worker = workers.setdefault(str(req.get("robot", "")), _Worker())
        try:
            reply = worker.handle(req)
        except Exception as exc:
            write_frame(stdout, {"fatal": f"{type(exc).__name__}: {exc}\n"
                                          f"{traceback.format_exc()}"})
            return 1
        write_frame(stdout, reply)
        if op == "load":  # (roger_daemon.daemon.gc_policy)
            thresholds = hold_collections() if thresholds is None else freeze_survivors()
        # after learning, when nothing waits: the labels of what was learned, then any
        # collection due (not after a prediction: in lockstep the other robots' answers of
        # the same tick need the cores then)
        if op == "learn" and not select.select([stdin], [], [], 0)[0]:
            _count_labels_ahead(worker)
            if thresholds is not None:
                collect_when_idle(thresholds)


def _count_labels_ahead(worker: _Worker) -> None:
    try:
        worker.idle()
    except Exception:  # only work ahead: the next prediction counts them itself
        if not worker.idle_failed:
            logging.getLogger(__name__).exception(
                "counting labels ahead failed; further failures are not logged")
        worker.idle_failed = True


if __name__ == "__main__":
    sys.exit(main())

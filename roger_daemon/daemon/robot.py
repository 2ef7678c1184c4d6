"""One served robot: its model, pairing by tick, the bounded training queue, labels, counters.

Everything here runs on the service loop's thread; nothing is shared with transport threads.

Intake (pairing by tick, the bounded training queue, re-sent pairs, a full disk, losses in
transport) is :class:`~roger_daemon.daemon.robot_intake.RobotIntake`, which the runtime extends.

Decisions: each learned pair, reset and dropped pair also goes to ``decisions`` (the session
log's decision records, docs/durability.md) when one is attached.

Labels: the daemon keeps the subtask label of every learned pair (as a code into a
vocabulary) and maps the model's ``assignments()`` to the majority label of each expert.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from protocols.errors import REASONS
from protocols.messages import (
    Dims,
    ExpertOutput,
    Perception,
    Prediction,
    encode_prediction,
)
from protocols.prediction_bytes import ExpertRow
from roger_daemon.config.settings import DaemonConfig
from roger_daemon.daemon.checkpoint_meta import Counters, LearnerSpec
from roger_daemon.daemon.pairing import PREDICT_MODES
from roger_daemon.daemon.robot_intake import RobotIntake
from roger_daemon.daemon.robot_state import NewestPair, Pair, RobotState
from roger_daemon.daemon.window import Window
from roger_daemon.labels import LabelTally, majority_labels_coded

__all__ = ["Decisions", "Pair", "RobotRuntime"]

log = logging.getLogger(__name__)


class Decisions(Protocol):
    """Where a runtime reports its decisions (the session log's decision records)."""

    def learned(self, rt: RobotRuntime, pair: Pair) -> None:
        """``pair`` became the model's pair number ``rt.updates - 1``."""

    def reset(self, rt: RobotRuntime, forgotten: int) -> None:
        """The model was replaced by a fresh one, forgetting ``forgotten`` pairs."""

    def dropped(self, rt: RobotRuntime, tick: int, reason: str) -> None:
        """A completed pair was not queued (``queue_full`` or ``resent``)."""


class RobotRuntime(RobotIntake):
    """The state the loop keeps for one robot.

    Parameters
    ----------
    robot
        The robot id.
    dims
        Perception / action sizes.
    model
        An object following ``docs/learner-api.md`` (``learn_one``, ``predict_one``,
        ``predict_multimap``, ``predict_with_multimap``, ``predict_table``, ``assignments``,
        ``n_experts``, ``n_learned``, ``state_dict``).
    make_model
        Builds a fresh model (used by the ``reset`` control).
    learner
        Which learner ``make_model`` builds (kind, seed, parameters), as checkpoints record it.
    mode
        Initial operating mode (one of ``protocols.messages.MODES``).
    """

    def __init__(
        self,
        robot: str,
        dims: Dims,
        model: Any,
        make_model: Callable[[], Any],
        *,
        mode: str = "learn+predict",
        queue_size: int = DaemonConfig.queue_size,
        pair_window: int = DaemonConfig.pair_window,
        learner: LearnerSpec | None = None,
    ) -> None:
        self.robot = robot
        self.dims = dims
        self.model = model
        self.make_model = make_model
        #: which learner the model is (its kind, seed, parameters): what checkpoints record
        self.learner = learner or LearnerSpec(str(getattr(model, "kind", "roger")))
        self.mode = mode
        self.queue_size = queue_size
        self.pair_window = pair_window
        self._init_intake(robot, pair_window)  # queue, pairing, intake counters
        self.vocab: list[str] = []
        self._vocab_index: dict[str, int] = {}
        self._codes = np.zeros(1024, dtype=np.int32)
        self.n_codes = 0
        # counters (restored from checkpoints; the intake's are in _init_intake)
        self.learn_errors = 0
        self.predict_errors = 0
        self.last_learned_tick: int | None = None  # tick of the newest learned pair
        self.session_resets = 0  # resets in this session (the log's segment number)
        self.recovered_pairs = 0  # pairs re-learned from the logs at start-up
        self.recovery = ""  # what start-up recovered from where (docs/durability.md)
        self.recovery_lost = 0  # pairs start-up found lost with no intact copy
        self._latency_ns = -1  # receipt time of the newest perception whose latency counted
        # windows and bookkeeping
        self.latency = Window()
        self.learn_ms = Window(200)
        self.predict_ms = Window(200)
        self.generation = 0  # bumped on every model change (learn, reset)
        self._labels_cache: tuple[int, dict[int, str]] | None = None
        self._tally = LabelTally()  # counts of the settled points (roger_daemon/labels.py)
        self._status_updates = 0
        self._status_ns: int | None = None
        # durability (roger_daemon.daemon.wal): every learned pair and fresh model is appended
        self.wal: Any = None
        self.decisions: Decisions | None = None  # roger_daemon.daemon.service.recording.DecisionLog

    # --- modes ---------------------------------------------------------------------------

    @property
    def predicting(self) -> bool:
        """Whether the current mode answers perceptions with predictions."""
        return self.mode in PREDICT_MODES

    @property
    def updates(self) -> int:
        """The model's ``n_learned``."""
        return int(self.model.n_learned)

    # --- learning and prediction -----------------------------------------------------------

    def add_latency(self, recv_ns: int, latency_ms: float) -> None:
        """Count a prediction's latency, once per perception: answering the same perception
        again (realtime, no newer one arrived: a link down) measures its age, not the daemon,
        and would have the status blame latency for an outage."""
        if recv_ns != self._latency_ns:
            self._latency_ns = recv_ns
            self.latency.add(latency_ms)

    def _dropped(self, tick: int, reason: str) -> None:
        if self.decisions is not None:
            self.decisions.dropped(self, tick, reason)

    def _label_code(self, label: str) -> int:
        code = self._vocab_index.get(label)
        if code is None:
            code = len(self.vocab)
            self.vocab.append(label)
            self._vocab_index[label] = code
        return code

    def learn_one(self) -> float:
        """Learn the oldest queued pair; return the time it took in ms (0 if queue empty)."""
        if not self.queue:
            return 0.0
        pair = self.queue.popleft()
        t0 = time.perf_counter_ns()
        try:
            self.model.learn_one(pair.x, pair.y)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            self.learn_errors += 1
            log.error("%s: learning the pair of tick %d failed (%s); pair skipped",
                      self.robot, pair.tick, exc)
            return (time.perf_counter_ns() - t0) / 1e6
        ms = (time.perf_counter_ns() - t0) / 1e6
        self.learned(pair, ms)
        return ms

    def learned(self, pair: Pair, ms: float) -> None:
        """Bookkeeping of a pair the model has just learned (here or in a worker process):
        its label code, its write-ahead log record, the counters."""
        self._append_code(pair.label)
        if self.wal is not None:
            self.wal.append_pair(self.updates - 1, pair.tick, pair.x, pair.y,
                                 self.vocab[pair.label])
        if self.decisions is not None:
            self.decisions.learned(self, pair)
        self.last_learned_tick = pair.tick
        self.generation += 1
        self.learn_ms.add(ms)

    def relearn(self, x: np.ndarray, y: np.ndarray, label: str, tick: int) -> None:
        """Learn a pair read back from the write-ahead log (start-up recovery).

        The queue restored from the checkpoint held this pair if it was queued then: it is
        taken off the queue's front. Not logged again; a re-sent copy of the newest pair is
        recognised afterwards and not learned twice.
        """
        if self.queue and self.queue[0].tick == tick and np.array_equal(self.queue[0].x, x):
            self.queue.popleft()
        self.model.learn_one(x, y)
        self._append_code(self._label_code(label))
        self.last_learned_tick = tick
        self.generation += 1
        self._newest_pair = (int(tick), np.asarray(x, dtype=np.float64).tobytes(),
                             np.asarray(y, dtype=np.float64).tobytes())

    def _append_code(self, code: int) -> None:
        if self.n_codes == len(self._codes):
            self._codes = np.concatenate([self._codes, np.zeros_like(self._codes)])
        self._codes[self.n_codes] = code
        self.n_codes += 1

    @property
    def codes(self) -> np.ndarray:
        """The expert code of every learned pair, in learning order."""
        return self._codes[: self.n_codes]

    def expert_labels(self) -> dict[int, str]:
        """Majority label of each expert of the MAP particle (cached per model generation)."""
        if self._labels_cache is not None and self._labels_cache[0] == self.generation:
            return self._labels_cache[1]
        codes = self.codes
        if int(self.model.n_learned) == len(codes):  # the usual case: O(unsettled points)
            labels = self._tally.labels(self.model, codes, self.vocab)
            self._labels_cache = (self.generation, labels)
            return labels
        assign = np.asarray(self.model.assignments(), dtype=np.int64)
        if len(assign) != len(codes):
            # Should not happen; keep going with what lines up and say so once.
            self._warn_once("labels", f"{self.robot}: {len(assign)} assignments but "
                            f"{len(codes)} labels; labels mapped on the common prefix")
            n = min(len(assign), len(codes))
            assign, codes = assign[:n], codes[:n]
        labels = majority_labels_coded(assign, codes, self.vocab)
        self._labels_cache = (self.generation, labels)
        return labels

    def predict(self, perc: Perception, recv_ns: int, now_ns: Callable[[], int]) -> Prediction:
        """The prediction for ``perc`` with the model as it is now."""
        t0 = time.perf_counter_ns()
        p, rows = self._predict_rows(perc.x)
        multimap = tuple(ExpertOutput(*row) for row in rows)
        self.predict_ms.add((time.perf_counter_ns() - t0) / 1e6)
        latency_ms = (now_ns() - recv_ns) / 1e6
        self.add_latency(recv_ns, latency_ms)
        return Prediction(
            self.robot, perc.tick, perc.t, mean=p.mean, var=p.var, expert=int(p.expert_id),
            multimap=multimap, latency_ms=latency_ms, mode=self.mode, updates=self.updates,
        )

    def answer(self, perc: Perception) -> dict[str, Any]:
        """The answer to ``perc``, inline or in a worker: ``ok``, ``pred`` (the daemon's one
        prediction encoding, the bytes of ``encode(self.predict(...))``; the loop stamps its
        publish-time fields) and ``ms``; or ``ok`` false and ``error``."""
        t0 = time.perf_counter_ns()
        try:
            p, rows = self._predict_rows(perc.x)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        pred = encode_prediction(self.robot, perc.tick, perc.t, mean=p.mean, var=p.var,
                                 expert=int(p.expert_id), multimap=rows, mode=self.mode,
                                 updates=self.updates)
        return {"ok": True, "pred": pred, "ms": (time.perf_counter_ns() - t0) / 1e6}

    def _predict_rows(self, x: np.ndarray) -> tuple[Any, list[ExpertRow]]:
        """The model's answer for ``x`` and its multimap as :class:`ExpertOutput` rows."""
        p, table = self.model.predict_table(x)  # gates and GPs evaluated once
        labels = self.expert_labels() if table.expert_ids else {}
        means, var = table.means.tolist(), table.variances.tolist()  # rows of floats
        rows = [(e, g, means[j], var[j], n, labels.get(e, ""))
                for j, (e, g, n) in enumerate(zip(table.expert_ids, table.gate_probs,
                                                  table.n_points, strict=True))]
        return p, rows

    # --- control ---------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget everything learned: a fresh model, no labels, empty queue and buffers."""
        forgotten = self.updates if self.model is not None else 0
        self.model = self.make_model()
        if self.wal is not None:
            self.wal.append_fresh()
        self.queue.clear()
        self.pairing.clear()
        self.vocab, self._vocab_index = [], {}
        self.n_codes = 0
        self.generation += 1
        self.session_resets += 1
        self.last_learned_tick = None
        self._labels_cache = None
        self._tally = LabelTally()
        self._status_updates = 0
        self._newest_pair = None
        if self.decisions is not None:
            self.decisions.reset(self, forgotten)

    # --- status ----------------------------------------------------------------------------

    def updates_per_s(self, now_ns: int) -> float:
        """Updates per second since the previous call (0 on the first)."""
        u = self.updates
        rate = 0.0
        if self._status_ns is not None and now_ns > self._status_ns:
            rate = max(0, u - self._status_updates) / ((now_ns - self._status_ns) / 1e9)
        self._status_ns, self._status_updates = now_ns, u
        return rate

    # --- checkpoint state ------------------------------------------------------------------

    def daemon_arrays(self, ahead: Sequence[Pair] = ()) -> dict[str, np.ndarray]:
        """Daemon state that must survive a restart, as named arrays (``ahead``: pairs
        taken off the queue but not yet learned, saved in front of it)."""
        newest = None
        if self._newest_pair is not None:  # a re-sent copy is recognised after a restart too
            tick, xb, yb = self._newest_pair
            newest = NewestPair(tick, np.frombuffer(xb, dtype=np.float64),
                                np.frombuffer(yb, dtype=np.float64))
        return RobotState(list(self.vocab), self.codes, [*ahead, *self.queue],
                          newest).to_arrays(self.dims)

    def counters(self, invalid: Mapping[str, int] | None = None) -> Counters:
        """The runtime's counters, as checkpointed (``invalid``: the rejections to report,
        by default the robot's own)."""
        return Counters(self.ticks, self.dropped, self.unpaired, self.learn_errors,
                        self.last_tick, self.last_t, self.mode, self.last_learned_tick,
                        dict(self.invalid if invalid is None else invalid))

    def restore(self, arrays: dict[str, np.ndarray], counters: Counters) -> None:
        """Load daemon state saved by :meth:`daemon_arrays` / :meth:`counters`
        (:class:`~roger_daemon.daemon.robot_state.RobotState`)."""
        state = RobotState.from_arrays(arrays)
        self.vocab = state.vocab
        self._vocab_index = {s: i for i, s in enumerate(self.vocab)}
        self._codes = np.zeros(max(1024, 2 * state.n_learned), dtype=np.int32)
        self._codes[: state.n_learned] = state.codes
        self.n_codes = state.n_learned
        self.queue.clear()
        self.queue.extend(state.queue)
        n = state.newest
        self._newest_pair = None if n is None else (n.tick, n.x.tobytes(), n.y.tobytes())
        self.ticks, self.dropped = counters.ticks, counters.dropped
        self.unpaired, self.learn_errors = counters.unpaired_actions, counters.learn_errors
        self.last_tick, self.last_t = counters.last_tick, counters.last_t
        llt = counters.last_learned_tick
        self.last_learned_tick = llt if self.n_codes else None
        self.invalid = Counter({k: v for k, v in counters.invalid.items() if k in REASONS})
        self._labels_cache = None
        self._tally = LabelTally()

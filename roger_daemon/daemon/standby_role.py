"""What a hot standby keeps per robot (:class:`RobotRole`) and the decisions a serving daemon
publishes for it (:class:`Replicated`); the protocol is :mod:`roger_daemon.daemon.standby`'s
(docs/daemon.md, *Hot standby*)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from protocols.decisions import Dropped, Learned, Reset
from protocols.message_types import Message, encode
from protocols.messages import Action, Perception
from roger_daemon.daemon.checkpoint_meta import CheckpointMeta
from roger_daemon.daemon.pairing import Pairing
from roger_daemon.daemon.robot import Decisions, Pair, RobotRuntime
from roger_daemon.transport import Publisher

__all__ = ["DECIDED_KEEP", "Replicated", "RobotRole"]

#: recent decided pairs kept to recognise a robot's message that arrives after its record
DECIDED_KEEP = 256


@dataclass
class RobotRole:
    """What the hot standby keeps for one robot (module doc)."""

    robot: str
    active: bool
    mode: str  # the robot's mode as the serving daemon has it (mode controls)
    epoch: int = 0
    token: str = ""  # our active token's key while we serve the robot
    holders: dict[str, int] = field(default_factory=dict)  # other daemons serving it: epoch
    last_epoch: int = -1  # the highest epoch seen for this robot
    seen_holder: bool = False
    next_updates: int = 1  # the ``updates`` of the next decided pair
    missing: int = 0  # decided pairs whose records never came (gaps)
    followed: int = 0  # decided pairs queued from records
    takeovers: int = 0
    tail_pairs: int = 0  # held pairs queued at the last takeover
    pairing: Pairing = field(default_factory=Pairing)
    held: deque[tuple[Perception, Action]] = field(default_factory=deque)
    decided: deque[tuple[int, bytes]] = field(default_factory=lambda: deque(maxlen=DECIDED_KEEP))
    newest: tuple[Perception, int] | None = None
    # catching up (standby_sync.py): live records held while the answer is awaited
    syncing: bool = False
    sync_sent_ns: int = 0
    pending: list[tuple[Message, str]] = field(default_factory=list)
    resync: bool = False  # a reset came while syncing: ask again once caught up
    synced_with: tuple[str, int] | None = None  # (daemon, epoch) of the last catch-up
    syncs: int = 0

    def hold(self, pair: tuple[Perception, Action] | None) -> None:
        """Hold a pair this daemon formed until its record lets it go (or a takeover)."""
        if pair is None:
            return
        perc, act = pair
        if (act.tick, perc.x.tobytes()) in self.decided:
            return  # its record came first
        self.held.append(pair)
        while len(self.held) > 4 * self.pairing.window:
            self.held.popleft()

    def unhold(self, tick: int, x: bytes | None) -> None:
        """Let the held pair of a decision record go (and the older ones the serving daemon
        passed over); remember it if it has not come yet."""
        for i, (perc, act) in enumerate(self.held):
            if act.tick == tick and (x is None or perc.x.tobytes() == x):
                for _ in range(i + 1):
                    self.held.popleft()
                return
        self.decided.append((tick, b"" if x is None else x))


class Replicated:
    """A robot's :class:`~roger_daemon.daemon.robot.Decisions`: the session log's (``inner``)
    and, while this daemon serves the robot, published for a standby."""

    def __init__(self, inner: Decisions | None, role: RobotRole,
                 pubs: Mapping[str, Publisher], wall_ns: Callable[[], int]) -> None:
        self.inner = inner
        self.role = role
        self.pubs = dict(pubs)
        self.wall_ns = wall_ns

    def _put(self, event: str, record: Message) -> None:
        if self.role.active:
            self.pubs[event].put(encode(record))

    def learned(self, rt: RobotRuntime, pair: Pair) -> None:
        """``pair`` became model pair ``rt.updates - 1``."""
        if self.inner is not None:
            self.inner.learned(rt, pair)
        label = rt.vocab[pair.label] if 0 <= pair.label < len(rt.vocab) else ""
        self._put("learned", Learned(rt.robot, pair.tick, pair.t, updates=rt.updates,
                                     segment=rt.session_resets, x=pair.x, y=pair.y,
                                     label=label, stamp_ns=self.wall_ns()))

    def reset(self, rt: RobotRuntime, forgotten: int) -> None:
        """The model was replaced by a fresh one."""
        if self.inner is not None:
            self.inner.reset(rt, forgotten)
        self._put("reset", Reset(rt.robot, rt.last_tick, rt.last_t, segment=rt.session_resets,
                                 forgotten=forgotten, stamp_ns=self.wall_ns()))

    def dropped(self, rt: RobotRuntime, tick: int, reason: str) -> None:
        """The completed pair of ``tick`` was not queued."""
        if self.inner is not None:
            self.inner.dropped(rt, tick, reason)
        self._put("dropped", Dropped(rt.robot, tick, rt.last_t, reason=reason,
                                     queue_size=rt.queue_size, dropped=rt.dropped,
                                     stamp_ns=self.wall_ns()))

    def checkpoint(self, rt: RobotRuntime, meta: CheckpointMeta) -> None:
        """A checkpoint was written: into the session log's digest chain."""
        chained = getattr(self.inner, "checkpoint", None)
        if chained is not None:
            chained(rt, meta)

"""Hot standby over Zenoh: one daemon serves a robot, another learns the same pairs and takes
the robot over when the first one's liveliness token goes (docs/daemon.md, *Hot standby*).

The model is a pure function of the daemon's decisions (docs/durability.md, *The decision
log*): the pairs it learned, in order, and its resets. So the serving daemon publishes them
(``learned``, ``reset``, ``dropped`` on ``roger/@daemon/<id>/replica/<robot>/<event>``) as it
makes them, and a standby queues exactly those pairs (the ``x``/``y`` floats of the record, bit
for bit) instead of pairing the robot's messages on its own: the same pairs, the same order,
the same model digest. Every decision record carries ``updates``; a record that does not
follow the previous one is a gap, counted and shown in status (``info.standby_missing``).

The standby still pairs the robot's messages, in a pairing of its own whose pairs are only
held: a pair the serving daemon learned is taken off when its record arrives. At a takeover
the pairs still held (the serving daemon died before their records reached the standby, or
before it learned them) are queued like any new pair, and the standby's pairing becomes the
robot's, so no pair the dead daemon may have acknowledged is missing.

Who serves: the daemon that holds ``roger/@daemon/<id>/active/<robot>/<epoch>``. A standby
takes a robot over when no such token is left, with an epoch one higher than the last it
saw. A primary starting while another daemon holds the robot's token starts as its standby
(a restarted primary does not split the brain). Two tokens for one robot (two daemons took
it at once) are resolved the same way everywhere: the higher epoch keeps the robot, then the
smaller daemon id; the other one becomes a standby.

Everything here runs on the service loop's thread: token changes and decision records
arrive through the loop's inbox like every other sample.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from protocols import keys
from protocols.decisions import Dropped, Learned, Reset, decode_decision
from protocols.errors import ProtocolError
from protocols.message_types import Message, encode
from protocols.messages import Action, Control, Perception
from roger_daemon.daemon.checkpoint_meta import CheckpointMeta
from roger_daemon.daemon.pairing import Pairing
from roger_daemon.daemon.robot import Decisions, Pair, RobotRuntime
from roger_daemon.transport import TOKEN_ALIVE, Incoming, Publisher

if TYPE_CHECKING:
    from roger_daemon.daemon.service.loop import Service

__all__ = ["Replicated", "Replication", "RobotRole"]

log = logging.getLogger(__name__)

#: how long a starting primary looks for another daemon's token of its robots (s)
LOOK_S = 1.0
#: recent decided pairs kept to recognise a robot's message that arrives after its record
DECIDED_KEEP = 256
#: a standby serves a robot nobody has served yet after this many status periods
UNSERVED_PERIODS = 5


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


class Replicated:
    """A robot's :class:`~roger_daemon.daemon.robot.Decisions`: the session log's (``inner``)
    and, while this daemon serves the robot, published for a standby."""

    def __init__(self, inner: Decisions | None, role: RobotRole,
                 pubs: Mapping[str, Publisher], wall_ns: Any) -> None:
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


class Replication:
    """The hot standby of one :class:`~roger_daemon.daemon.service.loop.Service` (module doc).

    The service calls :meth:`start` once its transport is up, :meth:`intercept` with every
    inbox item before admission, :meth:`passive` and :meth:`take` with each admitted message
    of a robot, and :meth:`poll` every cycle.
    """

    def __init__(self, svc: Service) -> None:
        self.svc = svc
        self.daemon = svc.config.id
        standby = svc.config.role == "standby"
        self.roles = {r: RobotRole(r, active=not standby, mode=rt.mode)
                      for r, rt in svc.robots.items()}
        self._start_ns = 0
        self._unserved_ns = 0

    # --- start -----------------------------------------------------------------------------

    def start(self, now: int) -> None:
        """Publishers, the decision-record and token subscriptions; which robots we serve."""
        svc, tr = self.svc, self.svc.transport
        self._start_ns = now
        self._unserved_ns = UNSERVED_PERIODS * int(round(1e9 / svc.config.status_hz))
        for robot, role in self.roles.items():
            rt = svc.robots[robot]
            pubs = {ev: tr.publisher(keys.replica(self.daemon, robot, ev), realtime=False)
                    for ev in ("learned", "reset", "dropped")}
            rt.decisions = Replicated(rt.decisions, role, pubs, svc.clock.time_ns)
            tr.subscribe(keys.replicas(robot), svc.inbox.put)
            role.next_updates = rt.updates + len(rt.queue) + 1
            if role.active:  # a primary: is another daemon serving it already?
                for key in tr.alive_tokens(keys.active_tokens(robot), LOOK_S):
                    self._token(key, alive=True, starting=True)
            if role.active:
                self._declare(role, role.epoch)
            else:
                self._become_passive(rt, role)
        tr.watch_tokens(keys.active_tokens(), svc.inbox.put)

    # --- the loop's hooks ------------------------------------------------------------------

    def intercept(self, item: Incoming) -> bool:
        """Handle ``item`` if it is a token change or a decision record; whether it was."""
        if keys.parse_active(item.key) is not None:
            self._token(item.key, alive=item.payload == TOKEN_ALIVE)
            return True
        where = keys.parse_replica(item.key)
        if where is None:
            return False
        daemon, robot, event = where
        role = self.roles.get(robot)
        if role is None or role.active or daemon == self.daemon or item.payload is None:
            return True  # not ours to follow (a split brain's records are resolved by tokens)
        rt = self.svc.robots[robot]
        try:
            msg = decode_decision(event, item.payload, dims=rt.dims, robot=robot)
        except ProtocolError as exc:
            rt.count_invalid(exc.reason, f"decision record from {daemon}: {exc.detail}")
            return True
        self._follow(rt, role, msg, daemon)
        return True

    def passive(self, robot: str) -> bool:
        """Whether we only follow ``robot`` (another daemon serves it)."""
        role = self.roles.get(robot)
        return role is not None and not role.active

    def take(self, rt: RobotRuntime, msg: Message, recv_ns: int) -> None:
        """An admitted message of a robot we follow: counted, paired and held."""
        role = self.roles[rt.robot]
        if isinstance(msg, Perception):
            rt.ticks += 1
            rt.last_tick, rt.last_t = msg.tick, msg.t
            role.newest = (msg, recv_ns)
            self._hold(role, role.pairing.perception(msg))
        elif isinstance(msg, Action):
            self._hold(role, role.pairing.action(msg))
        elif isinstance(msg, Control) and msg.op == "mode":
            role.mode = msg.mode  # reset comes as a record; checkpoints are the server's

    def poll(self, now: int) -> None:
        """A standby serves a robot nobody has served since it started (for a while)."""
        for robot, role in self.roles.items():
            if (not role.active and not role.holders and not role.seen_holder
                    and now - self._start_ns >= self._unserved_ns):
                log.warning("%s: no daemon has served it since we started; serving it", robot)
                self._take_over(robot, role, "")

    def info(self, robot: str) -> dict[str, Any]:
        """The robot's role for its status (``info``)."""
        role = self.roles[robot]
        return {"role": "primary" if role.active else "standby", "epoch": role.epoch,
                "standby_followed": role.followed, "standby_missing": role.missing,
                "standby_in_sync": role.missing == 0, "takeovers": role.takeovers,
                "takeover_tail_pairs": role.tail_pairs,
                "served_by": self.daemon if role.active else ",".join(sorted(role.holders))}

    # --- following -------------------------------------------------------------------------

    def _hold(self, role: RobotRole, pair: tuple[Perception, Action] | None) -> None:
        if pair is None:
            return
        perc, act = pair
        if (act.tick, perc.x.tobytes()) in role.decided:
            return  # its record came first
        role.held.append(pair)
        while len(role.held) > 4 * role.pairing.window:
            role.held.popleft()

    def _unhold(self, role: RobotRole, tick: int, x: bytes | None) -> None:
        """Take the held pair of a decision record off (and the older ones the serving daemon
        passed over); remember it if it has not come yet."""
        for i, (perc, act) in enumerate(role.held):
            if act.tick == tick and (x is None or perc.x.tobytes() == x):
                for _ in range(i + 1):
                    role.held.popleft()
                return
        role.decided.append((tick, b"" if x is None else x))

    def _follow(self, rt: RobotRuntime, role: RobotRole, msg: Message, daemon: str) -> None:
        from roger_daemon.daemon.service.controls import learn_before_reset

        if isinstance(msg, Learned):
            if msg.updates < role.next_updates:
                return  # a record we have (the serving daemon re-sent it)
            if msg.updates > role.next_updates:
                gap = msg.updates - role.next_updates
                role.missing += gap
                log.error("%s: %d decision records of %s never came (pairs %d-%d): this "
                          "standby's model is not the serving daemon's", rt.robot, gap, daemon,
                          role.next_updates, msg.updates - 1)
            rt.follow(msg.x, msg.y, msg.label, msg.tick)
            role.next_updates = msg.updates + 1
            role.followed += 1
            self._unhold(role, msg.tick, msg.x.tobytes())
        elif isinstance(msg, Reset):
            learn_before_reset(self.svc, rt)
            log.info("%s: %s reset the model: resetting ours", rt.robot, daemon)
            rt.reset()
            role.next_updates = 1
            role.held.clear()
            role.pairing.clear()
        elif isinstance(msg, Dropped):
            self._unhold(role, msg.tick, None)

    # --- tokens ----------------------------------------------------------------------------

    def _token(self, key: str, *, alive: bool, starting: bool = False) -> None:
        parsed = keys.parse_active(key)
        if parsed is None:
            return
        daemon, robot, epoch = parsed
        role = self.roles.get(robot)
        if role is None or daemon == self.daemon:
            return
        if alive:
            role.holders[daemon] = epoch
            role.seen_holder = True
            role.last_epoch = max(role.last_epoch, epoch)
            # a starting primary follows whoever serves; else the higher (epoch, rank) keeps it
            if role.active and (starting or
                                (epoch, _rank(daemon)) > (role.epoch, _rank(self.daemon))):
                self._yield(robot, role, daemon, starting=starting)
            return
        if role.holders.pop(daemon, None) is not None and not role.active and not role.holders:
            self._take_over(robot, role, daemon)

    def _declare(self, role: RobotRole, epoch: int) -> None:
        role.epoch = epoch
        role.token = keys.active_token(self.daemon, role.robot, epoch)
        self.svc.transport.declare_token(role.token)

    def _become_passive(self, rt: RobotRuntime, role: RobotRole) -> None:
        """Follow ``rt`` from now on: learn every decided pair, answer nothing."""
        role.mode = rt.mode
        rt.mode = "learn"  # decided pairs are learned whatever the robot's mode (module doc)
        rt.newest = None
        rt.pairing.clear()
        role.pairing = Pairing(rt.pair_window)
        role.held.clear()
        role.next_updates = rt.updates + len(rt.queue) + 1

    def _yield(self, robot: str, role: RobotRole, daemon: str, *, starting: bool) -> None:
        if starting:
            log.warning("%s: daemon %s serves it (epoch %d): starting as its standby", robot,
                        daemon, role.holders[daemon])
        else:
            log.error("%s: daemon %s serves it too (epoch %d); it keeps the robot, this "
                      "daemon becomes its standby", robot, daemon, role.holders[daemon])
        role.active = False
        if role.token:
            self.svc.transport.undeclare_token(role.token)
            role.token = ""
        self._become_passive(self.svc.robots[robot], role)

    def _take_over(self, robot: str, role: RobotRole, daemon: str) -> None:
        """Serve ``robot``: queue the held pairs, adopt the pairing, answer the newest."""
        from roger_daemon.daemon.service.answers import answer_now

        svc, rt = self.svc, self.svc.robots[robot]
        role.active = True
        role.takeovers += 1
        rt.mode = role.mode
        held, role.held = list(role.held), deque()
        role.tail_pairs = len(held)
        for perc, act in held:
            rt.enqueue_pair(perc, act)
        rt.pairing = role.pairing
        rt.newest = role.newest
        self._declare(role, role.last_epoch + 1)
        log.warning("%s: took over from %s (epoch %d): %d updates, %d decided pairs queued, "
                    "%d held pairs queued, %d never received", robot, daemon or "nobody",
                    role.epoch, rt.updates, len(rt.queue) - len(held), len(held), role.missing)
        if rt.newest is not None and rt.predicting and svc.config.clock == "lockstep":
            perc, recv_ns = rt.newest  # its sender waits for this answer
            answer_now(svc, rt, perc, recv_ns)


def _rank(daemon: str) -> tuple[int, ...]:
    """Order of daemon ids in a tie of epochs: the smaller id ranks higher (keeps the robot)."""
    return tuple(-ord(c) for c in daemon) + (0,)

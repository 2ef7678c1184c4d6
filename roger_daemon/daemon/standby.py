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
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from protocols import keys
from protocols.decisions import Dropped, Learned, Reset, decode_decision
from protocols.errors import ProtocolError
from protocols.message_types import Message
from protocols.messages import Action, Control, Perception
from roger_daemon.config import DaemonConfig
from roger_daemon.daemon.pairing import Pairing
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.standby_role import Replicated, RobotRole
from roger_daemon.daemon.standby_sync import SyncError, history, install
from roger_daemon.transport import TOKEN_ALIVE, Incoming

if TYPE_CHECKING:
    from roger_daemon.daemon.service.loop import Service

__all__ = ["Replication"]

log = logging.getLogger(__name__)

#: how long a starting primary looks for another daemon's token of its robots (s)
LOOK_S = 1.0
#: a catch-up query unanswered this long is given up (the gap is then counted)
SYNC_TIMEOUT_S = 10.0
#: a standby serves a robot nobody has served yet after this many status periods
UNSERVED_PERIODS = 5


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
        """Publishers, the decision-record and token subscriptions, the catch-up queryable;
        which robots we serve."""
        svc, tr = self.svc, self.svc.transport
        self._start_ns = now
        self._unserved_ns = UNSERVED_PERIODS * int(round(1e9 / svc.config.status_hz))
        for robot, role in self.roles.items():
            rt = svc.robots[robot]
            pubs = {ev: tr.publisher(keys.replica(self.daemon, robot, ev), realtime=False)
                    for ev in ("learned", "reset", "dropped")}
            rt.decisions = Replicated(rt.decisions, role, pubs, svc.clock.time_ns)
            tr.subscribe(keys.replicas(robot), svc.inbox.put)
            tr.serve(keys.sync(self.daemon, robot), _answer(svc.config, robot))
            role.next_updates = rt.updates + len(rt.queue) + 1
            if not role.active:  # a standby
                self._become_passive(rt, role)
                continue
            for key in tr.alive_tokens(keys.active_tokens(robot), LOOK_S):
                self._token(key, alive=True, starting=True)  # another daemon serves it?
            if role.active:
                self._declare(role, role.epoch)
        tr.watch_tokens(keys.active_tokens(), svc.inbox.put)

    # --- the loop's hooks ------------------------------------------------------------------

    def intercept(self, item: Incoming) -> bool:
        """Handle ``item`` if it is a token change, a decision record or a catch-up answer;
        whether it was one."""
        if keys.parse_active(item.key) is not None:
            self._token(item.key, alive=item.payload == TOKEN_ALIVE)
            return True
        synced = keys.parse_sync(item.key)
        if synced is not None:
            role = self.roles.get(synced[1])
            if role is not None and role.syncing and not role.active:
                if item.payload:
                    self._install(self.svc.robots[synced[1]], role, item.payload)
                else:  # the query ended unanswered
                    self._give_up(self.svc.robots[synced[1]], role,
                                  f"daemon {synced[0]} did not answer")
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
        if role.syncing and not isinstance(msg, Dropped):  # applied once caught up
            role.pending.append((msg, daemon))
            role.resync = role.resync or isinstance(msg, Reset)
        else:
            self._follow(rt, role, msg, daemon, live=True)
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
            role.hold(role.pairing.perception(msg))
        elif isinstance(msg, Action):
            role.hold(role.pairing.action(msg))
        elif isinstance(msg, Control) and msg.op == "mode":
            role.mode = msg.mode  # reset comes as a record; checkpoints are the server's

    def poll(self, now: int) -> None:
        """Catch-up queries unanswered too long; a standby serves a robot nobody has served
        since it started (for a while)."""
        for robot, role in self.roles.items():
            if role.syncing and now - role.sync_sent_ns >= int(SYNC_TIMEOUT_S * 1e9):
                self._give_up(self.svc.robots[robot], role, f"no answer in {SYNC_TIMEOUT_S} s")
            if (not role.active and not role.holders and not role.seen_holder
                    and now - self._start_ns >= self._unserved_ns):
                log.warning("%s: no daemon has served it since we started; serving it", robot)
                self._take_over(robot, role, "")

    def info(self, robot: str) -> dict[str, Any]:
        """The robot's role for its status (``info``)."""
        role = self.roles[robot]
        return {"role": "primary" if role.active else "standby", "epoch": role.epoch,
                "standby_followed": role.followed, "standby_missing": role.missing,
                "standby_in_sync": role.missing == 0 and not role.syncing,
                "standby_syncs": role.syncs, "takeovers": role.takeovers,
                "takeover_tail_pairs": role.tail_pairs,
                "served_by": self.daemon if role.active else ",".join(sorted(role.holders))}

    # --- following -------------------------------------------------------------------------

    def _follow(self, rt: RobotRuntime, role: RobotRole, msg: Message, daemon: str, *,
                live: bool) -> None:
        if isinstance(msg, Learned):
            if msg.updates < role.next_updates:
                return  # a record we have (a catch-up answer held it too)
            if msg.updates > role.next_updates:
                if live and self._sync(rt, role, daemon):
                    role.pending.append((msg, daemon))
                    return
                gap = msg.updates - role.next_updates
                role.missing += gap
                log.error("%s: %d decision records of %s never came (pairs %d-%d): this "
                          "standby's model is not the serving daemon's", rt.robot, gap, daemon,
                          role.next_updates, msg.updates - 1)
            rt.follow(msg.x, msg.y, msg.label, msg.tick)
            role.next_updates = msg.updates + 1
            role.followed += 1
            role.unhold(msg.tick, msg.x.tobytes())
        elif isinstance(msg, Reset):
            self.svc.controls.learn_before_reset(rt)
            log.info("%s: %s reset the model: resetting ours", rt.robot, daemon)
            rt.reset()
            role.next_updates = 1
            role.held.clear()
            role.pairing.clear()
        elif isinstance(msg, Dropped):
            role.unhold(msg.tick, None)

    # --- catching up (standby_sync.py) -----------------------------------------------------

    def _sync(self, rt: RobotRuntime, role: RobotRole, daemon: str) -> bool:
        """Ask ``daemon`` for its state of ``rt``; whether we now wait for it."""
        if not self.svc.learners.in_process:
            log.error("%s: a standby with learner worker processes cannot catch up (the "
                      "model lives in a worker); set [daemon] workers = \"inline\"", rt.robot)
            return False
        if role.syncing:
            return True
        role.syncing, role.pending = True, []
        role.sync_sent_ns = self.svc.clock.monotonic_ns()
        log.info("%s: catching up with %s (we have %d updates)", rt.robot, daemon, rt.updates)
        self.svc.transport.query(keys.sync(daemon, rt.robot), self.svc.inbox.put,
                                 SYNC_TIMEOUT_S)
        return True

    def _install(self, rt: RobotRuntime, role: RobotRole, payload: bytes) -> None:
        """The catch-up answer came: the serving daemon's state, then its records, ours."""
        try:
            daemon, records = install(rt, payload, self.svc.config.checkpoint.dir / rt.robot)
        except (SyncError, ProtocolError) as exc:
            self._give_up(rt, role, str(exc))
            return
        self.svc.checkpoints.write(rt, "synced", None, sync=True)  # our log starts from it
        role.syncing, role.missing, role.syncs = False, 0, role.syncs + 1
        role.synced_with = (daemon, role.holders.get(daemon, -1))
        role.next_updates = rt.updates + 1
        for msg in records:
            self._follow(rt, role, msg, daemon, live=False)
        log.info("%s: caught up with %s: %d updates from its checkpoint, %d records after it",
                 rt.robot, daemon, rt.updates, len(records))
        self._replay_pending(rt, role)
        if role.resync:  # a reset came meanwhile: which side of it the answer was is unsure
            role.resync = False
            self._sync(rt, role, daemon)

    def _give_up(self, rt: RobotRuntime, role: RobotRole, why: str) -> None:
        log.error("%s: catching up failed (%s); following with a gap", rt.robot, why)
        role.syncing = False
        self._replay_pending(rt, role)

    def _replay_pending(self, rt: RobotRuntime, role: RobotRole) -> None:
        pending, role.pending = role.pending, []
        for msg, daemon in pending:
            self._follow(rt, role, msg, daemon, live=False)

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
            elif not role.active and not starting and role.synced_with != (daemon, epoch):
                self._sync(self.svc.robots[robot], role, daemon)  # a new server: its state
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
        if not starting:  # at start: once the token watch delivers the server's token
            self._sync(self.svc.robots[robot], role, daemon)

    def _take_over(self, robot: str, role: RobotRole, daemon: str) -> None:
        """Serve ``robot``: queue the held pairs, adopt the pairing, answer the newest."""
        svc, rt = self.svc, self.svc.robots[robot]
        if role.syncing:
            self._give_up(rt, role, f"{daemon or 'the serving daemon'} went")
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
        log.warning("%s: took over from %s (epoch %d): %d updates, %d held pairs queued, %d "
                    "decided pairs never received", robot, daemon or "nobody", role.epoch,
                    rt.updates, len(held), role.missing)
        # before any answer (the realtime tick's too): it counts every pair the dead daemon
        # may have acknowledged
        svc.learners.learn_all(rt)
        if rt.newest is not None and rt.predicting and svc.config.clock == "lockstep":
            perc, recv_ns = rt.newest  # its sender waits for this answer
            svc.learners.predict(rt, perc, recv_ns)  # after learn_all: lockstep's order


def _answer(cfg: DaemonConfig, robot: str) -> Callable[[], bytes]:
    """The catch-up answer for ``robot``, computed when asked (on Zenoh's thread)."""
    return lambda: history(cfg, robot)


def _rank(daemon: str) -> tuple[int, ...]:
    """Order of daemon ids in a tie of epochs: the smaller id ranks higher (keeps the robot)."""
    return tuple(-ord(c) for c in daemon) + (0,)

"""``roger play``: the robot plays alone, on ROGER's experts and their learned transitions.

No hand-coded controller runs: this node imports nothing of :mod:`simulator.controllers.hcc`
and reads no demonstrator label (docs/autonomy.md; ``tests/test_play_node.py`` checks both).
It loads the learned transitions of a ``roger+fsm`` model from a daemon checkpoint
(``--checkpoint FILE`` or the newest valid one of ``--robot`` in a checkpoint directory), and
for every perception(t) takes the daemon's ``prediction``(t) (the daemon in predict mode
serving that checkpoint; ``--prediction-timeout`` seconds at most, matched by tick; in
``--clock realtime`` the newest prediction not older than ``--max-prediction-age`` ticks) and
publishes as ``command``(t) the mean of the expert the learned transitions choose among the
prediction's multimap (:class:`roger_daemon.fsm.player.Player`), ``source =
"play:<expert>:<how>"`` with ``how``:

- ``learned``: the learned transitions chose (the robot's learned state is that expert);
- ``empty_multimap``: the model has no expert -> the prediction's own ``mean``;
- ``no_prediction``: nothing arrived in time -> a hold command (stand still, head and tail
  where they are, no motion), as ``roger hcc --role transitioner`` does.

It never publishes ``action``, so a daemon in any mode learns nothing from it. A perception
with ``t == 0`` starts a new episode (the learned state restarts); a repeated tick gets the
cached command again; with ``--exit-when-done`` it exits on the simulator's final ``end``
event. On exit it prints one JSON line of counters (also to ``--stats FILE``), with the ticks
spent in each learned state.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from protocols import Command, Perception
from roger_daemon.fsm.player import Player, load_player
from simulator.controllers.node import PerceptionNode, add_node_args, hold
from simulator.transport import StopFlag, serve

__all__ = ["PlayNode", "configure", "hold", "run"]

log = logging.getLogger("roger.play")


def configure(parser: argparse.ArgumentParser) -> None:
    """Command-line arguments of ``roger play``."""
    parser.add_argument("--checkpoint", type=Path, required=True, metavar="PATH",
                        help="a daemon checkpoint of a roger+fsm model, or a checkpoint "
                             "directory (its newest valid checkpoint of --robot)")
    add_node_args(parser)


class PlayNode(PerceptionNode):
    """The player's step in the nodes' one loop (:mod:`simulator.controllers.node`)."""

    def __init__(self, args: argparse.Namespace, player: Player, stop: StopFlag) -> None:
        super().__init__(args, stop, "play", log, ("no_prediction",))
        self.player = player
        self.state_ticks: dict[str, int] = {}

    def run(self, session: Any) -> dict[str, Any]:
        """Serve until stopped, idle or the simulator's run is complete; the counters."""
        self.serve_perceptions(session, predictions=True)
        return self.summary(**self.player.counts, state_ticks=self.state_ticks)

    def new_episode(self) -> None:
        """The learned state restarts."""
        self.player.reset()

    def command_for(self, msg: Perception) -> Command:
        """The expert the learned transitions choose, or a hold command."""
        x = np.asarray(msg.x)
        pred = self.prediction_for(msg)
        if pred is None:
            self.counts["no_prediction"] += 1
            y = hold(x)
            self.player.commit(y)
            source = "play:-1:no_prediction"
        else:
            y, how = self.player.command(x, pred.multimap, pred.mean)
            state = self.player.state if how == "learned" else pred.expert
            source = f"play:{state}:{how}"
            key = str(self.player.state)
            self.state_ticks[key] = self.state_ticks.get(key, 0) + 1
        return Command(self.robot, msg.tick, msg.t, y=y, source=source)


def run(args: argparse.Namespace) -> int:
    """Load the learned transitions, then serve until stopped; print the counters."""
    try:
        player = load_player(args.checkpoint, args.robot)
    except (ValueError, OSError) as exc:
        print(f"roger play: {exc}", file=sys.stderr)
        return 2
    log.info("learned transitions from %s: %d states, %d transitions", args.checkpoint,
             len(player.fsm.transitions.sources()), len(player.fsm.transitions.pairs))
    serve(PlayNode(args, player, StopFlag()), args)
    return 0

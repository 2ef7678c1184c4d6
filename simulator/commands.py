"""The ``roger`` subcommands this package adds, found by ``roger_daemon.cli`` through the
``roger.commands`` entry point (pyproject.toml): the daemon package never names this one.

Same form as ``roger_daemon.cli.COMMANDS``: ``name -> (module, one-line help)``, each module
with ``configure(parser)`` and ``run(args)``, imported only when its subcommand runs.
"""

from __future__ import annotations

__all__ = ["BENCHES", "COMMANDS"]

COMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("simulator.sim_node", "the AIBO soccer simulator (pybullet) as a Zenoh process"),
    "hcc": ("simulator.controllers.hcc_node",
            "the hand-coded FSM goal scorer: demonstrator or transitioner"),
    "play": ("simulator.controllers.play_node",
             "the robot plays alone: ROGER's experts and their learned transitions, no HCC"),
    "experiment": ("simulator.experiment.cli", "experiments: goal-scoring (paper section IV)"),
    "demo": ("simulator.experiment.demo", "a short end-to-end session: demonstrate, learn, act"),
    "up": ("simulator.launch", "start daemon, simulator and controller from one TOML file"),
    "view": ("simulator.view.node", "live Foxglove view (WebSocket) of a session, or of a log"),
    "teach": ("simulator.teach.cli",
              "demonstrate, watch and correct the robot live from a web page"),
}

BENCHES: dict[str, tuple[str, str]] = {
    "sim": ("simulator.bench", "simulator lockstep ticks/s (rendered, fast) and HCC success"),
}

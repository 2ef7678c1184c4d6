"""``roger experiment NAME``: the experiments and their helper nodes.

* ``roger experiment goal-scoring --out DIR [--quick] [--seed S] [--jobs N]``: the paper's
  section IV end to end (:mod:`simulator.experiment.goal_scoring`);
* ``roger experiment peers --out DIR [--seed S] [--policies act,diffusion]``: LeRobot's ACT and
  Diffusion Policy on the same demonstrations (:mod:`simulator.experiment.peers`);
* ``roger experiment dpa``: the unimap baseline's controller node, executing each prediction's
  mean (:mod:`simulator.experiment.dpa_node`); the experiment starts it, one per job.
"""

from __future__ import annotations

import argparse
import importlib

__all__ = ["EXPERIMENTS", "configure", "run"]

# name -> (module, one-line help); each module has configure(parser) and run(args) -> int
EXPERIMENTS: dict[str, tuple[str, str]] = {
    "goal-scoring": ("simulator.experiment.goal_scoring",
                     "the paper's section IV: demonstrate, learn, evaluate, report"),
    "peers": ("simulator.experiment.peers",
              "LeRobot's ACT and Diffusion Policy on goal-scoring's demonstrations (the "
              "peers extra; docs/peers.md)"),
    "table": ("simulator.experiment.table",
              "a goal-scoring results.json as a Markdown table (the README's)"),
    "dpa": ("simulator.experiment.dpa_node",
            "unimap baseline controller: each prediction's mean as the command"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    """Add one sub-subcommand per experiment."""
    sub = parser.add_subparsers(dest="experiment", metavar="EXPERIMENT")
    sub.required = True
    for name, (module, help_text) in EXPERIMENTS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(module).configure(p)
        p.set_defaults(_experiment_module=module)


def run(args: argparse.Namespace) -> int:
    """Run the chosen experiment."""
    code: int = importlib.import_module(args._experiment_module).run(args)
    return code

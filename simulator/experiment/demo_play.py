"""``roger demo``'s last stage: the robot plays alone (``roger play``, no HCC; docs/autonomy.md).

The live daemon learned the demonstrations as a ``roger+fsm`` model, so its final checkpoint
(``OUT/checkpoints``) holds ROGER's experts and their learned transitions. The stage is what a
user does with a session of their own: a ``roger daemon`` in predict mode resumed from that
checkpoint directory, ``roger play --checkpoint OUT/checkpoints`` as the only controller and
``roger sim``, one episode from each demonstrated location; the summary says how often the
robot scored (goals / attempts).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["PLAY_MEANING", "controller_argv", "play_commands", "play_rows", "play_summary",
           "segmentation_figures"]

#: What the play episodes are (README's workflow for a session of one's own).
PLAY_MEANING = ("no hand-coded controller at all: `roger play` keeps the robot's learned "
                "state (an expert) and sends that expert's command; the learned transitions "
                "choose the next expert from the perception and the robot's memories. On "
                "demonstration streams 0-2 of the goal-scoring experiment this scores about "
                "0.25 x the HCC (docs/autonomy.md); after a few demonstrations it usually "
                "fails by kicking in place, switching between experts or standing still")


def controller_argv(role: str, out: Path) -> list[str]:
    """The controller's ``roger`` arguments for a stage: ``roger hcc --role ROLE``, or for
    ``play`` ``roger play`` on the live daemon's checkpoints."""
    if role == "play":
        return ["play", "--checkpoint", str(out / "checkpoints")]
    return ["hcc", "--role", role]


def play_summary(test: dict[str, Any], out: Path) -> dict[str, Any]:
    """The stage's part of ``summary.json``."""
    eps = test["episodes"]
    return {"episodes": eps, "goals": sum(bool(e["success"]) for e in eps),
            "attempts": len(eps), "controller": test["controller"],
            "checkpoint_dir": str(out / "checkpoints")}


def play_rows(table: Any, auto: dict[str, Any]) -> None:
    """The summary table's rows of the stage."""
    ctl = auto["controller"]
    table.add_row("learned transitions, no HCC (roger play)",
                  f"{auto['goals']} goals of {auto['attempts']} attempts: " + ", ".join(
                      f"location {e['location']}: [{'green' if e['success'] else 'red'}]"
                      f"{e['outcome']}[/]" for e in auto["episodes"]))
    table.add_row("commands chosen by (play)", ", ".join(
        f"{k} {ctl.get(k, 0)}" for k in ("learned", "empty_multimap", "no_prediction")))


def play_commands(out: Path) -> list[str]:
    """The plain lines that tell a user how to play (and read) a session of their own."""
    ck = out / "checkpoints"
    return [f"automaton:  roger model fsm {ck} --png fsm.png",
            f"play it:    roger play --checkpoint {ck}   (beside roger daemon in predict "
            "mode resumed from it and roger sim: roger up configs/up-play.toml)"]


def segmentation_figures(out: Path, model: Any) -> tuple[dict[int, str], Any, dict[str, Path],
                                                         list[Path]]:
    """The demo's segmentation against the HCC's labels (labels for these scores and figures
    only): ``(majority label per expert, scores or None, figures, the session's MCAP files)``."""
    import numpy as np

    from roger_daemon.labels import majority_labels
    from roger_daemon.recording import list_session_files, read_timeline
    from simulator.experiment.figures import plot_experts_histogram, plot_pca
    from simulator.experiment.metrics import segmentation_scores

    mcap = [sf.path for sf in list_session_files(out / "recordings", robot="aibo")]
    tl = read_timeline(mcap)
    x = np.array([p.x for p in tl.pairs])
    y = np.array([p.y for p in tl.pairs])
    labels = [p.label for p in tl.pairs]
    assign = np.asarray(model.assignments()).tolist()
    if not (len(assign) == len(labels) and labels):  # should not happen: log and checkpoint
        return {}, None, {}, mcap                    # disagree
    figs = {"Fig. 7 (PCA by subtask / expert / group)": plot_pca(
                x, y, labels, assign, out / "fig7_pca.png"),
            "Fig. 8 (data per expert)": plot_experts_histogram(
                assign, labels, out / "fig8_experts.png")}
    return majority_labels(assign, labels), segmentation_scores(assign, labels), figs, mcap

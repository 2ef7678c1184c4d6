"""``roger demo``: a short end-to-end session in separate processes (what ``make demo`` runs).

1. ``roger daemon`` (lockstep, learn+predict, recording to MCAP, checkpoints) on a free
   loopback port;
2. ``roger sim`` + ``roger hcc --role demonstrator``: the hand-coded controller scores from a
   few start locations while the daemon learns every pair live;
3. the daemon is switched to predict mode (a ``control`` message), and ``roger sim`` + ``roger
   hcc --role transitioner`` run one episode on the learned experts (the HCC picks, for its
   current subtask, the expert whose majority label is that subtask);
4. the daemon stops (final checkpoint), the figures of the learned segmentation are drawn from
   the recorded session and the checkpoint, and a summary is printed: experts found, the
   episode's outcome, where the MCAP log, checkpoint and figures are.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from roger_daemon.atomic import write_json

__all__ = ["OUTCOME_MEANING", "configure", "run"]

#: What each episode outcome the summary can print means (simulator/episodes.py OUTCOMES).
OUTCOME_MEANING = {
    "goal": "the ball crossed the opponent's goal line: success",
    "own_goal": "the ball went into the robot's own goal",
    "out": "the ball left the field over a sideline or an end line",
    "timeout": "no goal within the time limit (--time-limit). The learned controller often "
               "ends this way here: a few short demonstrations teach far less than the "
               "goal-scoring experiment's 130 (README, the paper's experiment)",
    "stopped": "the simulator was stopped before the episode ended",
}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger demo``."""
    parser.add_argument("--out", type=Path, default=Path("runs/demo"),
                        help="output directory (default runs/demo); what an earlier demo "
                             "wrote there is replaced, anything else is kept")
    parser.add_argument("--force", action="store_true",
                        help="use --out even if it holds files not written by roger demo "
                             "(they are deleted)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every process")
    parser.add_argument("--locations", default="0,1,3,6",
                        help="demonstration start locations (default 0,1,3,6)")
    parser.add_argument("--test-location", type=int, default=0,
                        help="start location of the learned controller's episode (default 0)")
    parser.add_argument("--time-limit", type=float, default=150.0,
                        help="simulated seconds per episode (default 150, the paper's)")
    parser.add_argument("--vision", choices=("rendered", "fast"), default="rendered",
                        help="the simulator's vision: rendered segmentation (default) or the "
                             "fast analytic projection")


class _Demo:
    def __init__(self, args: argparse.Namespace, console: Any) -> None:
        self.args = args
        self.console = console
        self.out: Path = args.out
        self.client: Any = None

    def _status(self, predicate: Any = None, timeout: float = 10.0) -> Any:
        return self.client.wait_status(predicate, timeout)

    def run(self) -> int:
        from roger_daemon.atomic import owned_output_dir

        with owned_output_dir(self.out, "demo", force=self.args.force):
            return self._run()

    def _run(self) -> int:
        from roger_daemon.harness import Client, DaemonProcess, write_config
        from simulator.episodes import START_LOCATIONS, parse_locations
        from simulator.experiment.procs import (
            CHILDREN,
            ProcessGroup,
            child_env,
            free_port,
            roger_argv,
        )

        args, console, out = self.args, self.console, self.out
        locations = parse_locations(args.locations)
        if not 0 <= args.test_location < len(START_LOCATIONS):
            raise ValueError(f"--test-location must be in 0..{len(START_LOCATIONS) - 1}")
        t_all = time.monotonic()
        port = free_port()
        daemon_ep = f"tcp/127.0.0.1:{port}"
        cfg = write_config(
            out / "daemon.toml", port=port, workdir=out,
            daemon={"mode": "learn+predict", "clock": "lockstep", "seed": args.seed,
                    "queue_size": 100_000},
            checkpoint={"on_shutdown": True, "every_updates": 0, "every_s": 0.0},
            recording={"enabled": True},
        )
        console.rule("roger demo")
        console.print(f"daemon on {daemon_ep}, demonstrations from locations {locations}, "
                      f"then the learned experts from location {args.test_location}; "
                      f"output in {out}")
        with CHILDREN.spawning():  # a stop reaches it (procs.stop_children_on_signals)
            daemon = DaemonProcess(cfg, args=["--fresh"], log=out / "daemon.log",
                                   env=child_env())
            CHILDREN.add(daemon.proc)
        summary: dict[str, Any] = {}
        try:
            daemon.wait_ready(120)
            self.client = Client(daemon_ep)
            self.client.wait_daemon(30)
            demo = self._episodes("demonstration", "demonstrator", locations, args.seed,
                                  daemon_ep, out / "demonstration", ProcessGroup, free_port,
                                  roger_argv)
            pairs = sum(e["ticks"] for e in demo["episodes"])
            try:
                st = self._status(lambda s: s.queue_depth == 0 and s.updates >= pairs, 60)
            except TimeoutError:  # a pair lost on the way: go on with what was learned
                st = self._status(lambda s: s.queue_depth == 0, 30)
                console.log(f"[yellow]the daemon learned {st.updates} of {pairs} pairs[/yellow]")
            console.log(f"daemon learned {st.updates} pairs: {st.experts} experts")
            self.client.control("mode", "predict")
            self._status(lambda s: s.mode == "predict", 10)
            test = self._episodes("learned experts + HCC transitioner", "transitioner",
                                  [args.test_location], args.seed + 1, daemon_ep,
                                  out / "transitioner", ProcessGroup, free_port, roger_argv)
            summary = {"demo": demo, "test": test, "updates": st.updates}
            self.client.close()
            self.client = None
            code, _ = daemon.terminate(60)
            if code != 0:
                raise RuntimeError(f"the daemon exited with {code}; see {out / 'daemon.log'}")
        finally:
            if self.client is not None:
                self.client.close()
            daemon.kill()
        self._report(summary, time.monotonic() - t_all)
        return 0

    def _episodes(self, title: str, role: str, locations: list[int], seed: int,
                  daemon_ep: str, workdir: Path, group_cls: Any, free_port: Any,
                  roger_argv: Any) -> dict[str, Any]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

        from simulator.experiment.procs import count_episodes

        args = self.args
        workdir.mkdir(parents=True, exist_ok=True)
        sim_port = free_port()
        group = group_cls(workdir)
        try:
            group.start("controller", roger_argv(
                "hcc", "--role", role, "--connect", f"tcp/127.0.0.1:{sim_port}",
                "--connect", daemon_ep, "--exit-when-done", "--idle-exit", "120",
                "--stats", str(workdir / "controller.json")))
            group.start("sim", roger_argv(
                "sim", "--clock", "lockstep", "--listen", f"tcp/127.0.0.1:{sim_port}",
                "--connect", daemon_ep, "--locations", ",".join(map(str, locations)),
                "--seed", str(seed), "--time-limit", repr(float(args.time_limit)),
                "--vision", args.vision, "--results", str(workdir / "sim.json"),
                "--wait-peers", "2", "--wait-subscribers", "60"))
            n = len(locations)
            with Progress(TextColumn("{task.description:<36}"), BarColumn(bar_width=20),
                          MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                          console=self.console) as progress:
                task = progress.add_task(title, total=n, info="")
                proc = group.procs["sim"].popen
                while proc.poll() is None:
                    time.sleep(0.5)
                    progress.update(task, completed=min(count_episodes(group.procs["sim"].log),
                                                        n), info=self._info())
                progress.update(task, completed=n, info=self._info())
            if proc.returncode != 0:
                raise RuntimeError(f"roger sim exited with {proc.returncode}" + group.tails())
            group.wait("controller", 60)
        finally:
            group.close()
        sim = json.loads((workdir / "sim.json").read_text())
        ctl = json.loads((workdir / "controller.json").read_text())
        for e in sim["episodes"]:
            self.console.log(f"{role}: location {e['location']} ({e['location_name']}): "
                             f"{e['outcome']} after {e['sim_time_s']:.1f} s")
        return {"episodes": sim["episodes"], "summary": sim["summary"], "controller": ctl}

    def _info(self) -> str:
        st = self.client.statuses[-1].msg if self.client and self.client.statuses else None
        if st is None:
            return ""
        return f"{st.updates} learned, {st.experts} experts, {st.mode}"

    def _report(self, summary: dict[str, Any], wall: float) -> None:
        from rich.table import Table

        from roger_daemon.daemon.checkpoint import load_newest
        from roger_daemon.labels import majority_labels
        from roger_daemon.learner import load_model
        from roger_daemon.recording import list_session_files, read_timeline
        from simulator.experiment.figures import plot_experts_histogram, plot_pca
        from simulator.experiment.metrics import segmentation_scores

        out = self.out
        ck = load_newest(out / "checkpoints", "aibo")
        if ck is None:
            raise RuntimeError("the daemon wrote no checkpoint")
        model = load_model(ck.model)
        mcap = [sf.path for sf in list_session_files(out / "recordings", robot="aibo")]
        tl = read_timeline(mcap)
        import numpy as np

        x = np.array([p.x for p in tl.pairs])
        y = np.array([p.y for p in tl.pairs])
        labels = [p.label for p in tl.pairs]
        assign = np.asarray(model.assignments()).tolist()
        figs = {}
        if len(assign) == len(labels) and labels:
            groups = majority_labels(assign, labels)
            seg = segmentation_scores(assign, labels)
            figs["Fig. 7 (PCA by subtask / expert / group)"] = plot_pca(
                x, y, labels, assign, out / "fig7_pca.png")
            figs["Fig. 8 (data per expert)"] = plot_experts_histogram(
                assign, labels, out / "fig8_experts.png")
        else:  # should not happen: the log and the checkpoint disagree
            groups, seg = {}, None
        test = summary["test"]["episodes"][0]
        ctl = summary["test"]["controller"]
        t = Table(title="roger demo: summary", show_header=False)
        t.add_column("what")
        t.add_column("value")
        demo_eps = summary["demo"]["episodes"]
        t.add_row("demonstrations", ", ".join(f"location {e['location']}: {e['outcome']}"
                                              for e in demo_eps))
        t.add_row("pairs learned live", str(model.n_learned))
        per = ", ".join(f"{k} {v}" for k, v in sorted(
            {lab: list(groups.values()).count(lab) for lab in set(groups.values())}.items()))
        t.add_row("experts found", f"{model.n_experts} (by majority subtask: {per})")
        if seg is not None:
            t.add_row("segmentation vs HCC labels",
                      f"purity {seg.purity:.2f}, ARI {seg.ari:.2f}, NMI {seg.nmi:.2f}")
        outcome = test["outcome"]
        style = "green" if test["success"] else "red"
        t.add_row("learned experts + HCC transitioner",
                  f"[{style}]{outcome}[/{style}] from location {test['location']} after "
                  f"{test['sim_time_s']:.1f} s simulated")
        t.add_row("commands chosen by", ", ".join(
            f"{k} {ctl.get(k, 0)}" for k in ("label", "fallback_top", "fallback_mean",
                                             "no_prediction")))
        t.add_row("wall time", f"{wall:.0f} s")
        self.console.print(t)
        # paths and commands as plain lines, never wrapped, so that they can be copied
        import textwrap

        for text in (f"outcome {outcome}: {OUTCOME_MEANING.get(outcome, outcome)}",
                     "commands chosen by: label = an expert whose majority label is the FSM's "
                     "subtask; fallback_top = no such expert, the most probable one; "
                     "fallback_mean = an empty multimap, the prior mean; no_prediction = none "
                     "in time, the robot stood still"):
            print(textwrap.fill(text, 78, subsequent_indent="  "))
        for p in mcap:
            print(f"MCAP log:   {p}")
        print(f"checkpoint: {ck.path}")
        for name, path in figs.items():
            print(f"figure:     {path}   ({name})")
        if mcap:
            print(f"replay it:  roger replay {mcap[0]}")
        write_json(out / "summary.json", {
            "experts": int(model.n_experts),
            "pairs": int(model.n_learned),
            "expert_labels": {str(k): v for k, v in sorted(groups.items())},
            "demonstrations": demo_eps,
            "test_episode": test,
            "transitioner": ctl,
            "mcap": [str(p) for p in mcap],
            "checkpoint": str(ck.path),
            "figures": {k: str(v) for k, v in figs.items()},
            "wall_s": round(wall, 1),
        }, default=str)


def run(args: argparse.Namespace) -> int:
    """Run the demo; 0 when every process did its part (whatever the episode's outcome)."""
    from rich.console import Console

    from roger_daemon.atomic import OutputDirError
    from simulator.experiment.procs import stop_children_on_signals

    console = Console()
    stop_children_on_signals()
    try:
        return _Demo(args, console).run()
    except OutputDirError as exc:
        print(f"roger demo: {exc}", file=sys.stderr)
        return 2
    except (RuntimeError, TimeoutError, ValueError, OSError) as exc:
        console.print(f"[red]roger demo failed:[/red] {exc}")
        print(f"roger demo: {exc}", file=sys.stderr)
        return 1

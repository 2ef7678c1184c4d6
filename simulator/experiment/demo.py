"""``roger demo``: a short end-to-end session in separate processes (what ``make demo`` runs).

1. ``roger daemon`` (lockstep, learn+predict, recording to MCAP, checkpoints) on a free
   loopback port;
2. ``roger sim`` + ``roger hcc --role demonstrator``: the hand-coded controller scores from a
   few start locations while the daemon learns every pair live;
3. the daemon is switched to predict mode (a ``control`` message), and ``roger sim`` + ``roger
   hcc --role transitioner`` run one episode on the learned experts (the HCC picks, for its
   current subtask, the expert whose majority label is that subtask);
4. the daemon stops (final checkpoint); ``roger replay LOG --merge-groups --save-checkpoint
   OUT/merged`` refits each group of experts (a majority label) as one expert, a second
   ``roger daemon`` serves that checkpoint in predict mode, and the same transitioner runs one
   episode on it from each demonstrated location (the README's workflow for a session of your
   own);
5. the robot plays alone (:mod:`.demo_play`): the live daemon learned a ``roger+fsm`` model,
   so its final checkpoint holds the experts' learned transitions; a daemon in predict mode
   serves it and ``roger play`` (no HCC process) drives one episode from each demonstrated
   location;
6. the figures of the learned segmentation are drawn from the recorded session and the
   checkpoint, and a summary is printed: experts found, the episodes' outcomes (the robot's
   own goals / attempts), where the MCAP log, checkpoints and figures are.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from roger_daemon.atomic import write_json
from roger_daemon.config.settings import FSM_MODEL
from roger_daemon.tools.common import port
from simulator.experiment.demo_play import (
    PLAY_MEANING,
    controller_argv,
    play_commands,
    play_rows,
    play_summary,
)
from simulator.experiment.goal_plan import DEFAULT_TIME_LIMIT

__all__ = ["MERGED_MEANING", "OUTCOME_MEANING", "configure", "run"]

#: What each episode outcome the summary can print means (simulator/episodes.py OUTCOMES).
OUTCOME_MEANING = {
    "goal": "the ball crossed the opponent's goal line: success",
    "own_goal": "the ball went into the robot's own goal",
    "out": "the ball left the field over a sideline or an end line",
    "timeout": "no goal within the time limit (--episode-duration). The learned controller often "
               "ends this way here: a few short demonstrations teach far less than the "
               "goal-scoring experiment's 130 (README, the paper's experiment)",
    "stopped": "the simulator was stopped before the episode ended",
}


#: What the merged-groups episode is (README, the paper's experiment).
MERGED_MEANING = ("each group of experts (those sharing a majority label) refitted as one "
                  "expert by `roger replay --merge-groups`, the command printed below, and "
                  "served by a daemon in predict mode. In the goal-scoring experiment this "
                  "controller scored in 85 % of the episodes on the reference demonstrations "
                  "and 71 % across three demonstration streams (README), each of 130 "
                  "demonstrations. Here a subtask that the few demonstrations never showed "
                  "has no group, and its commands fall back to the most probable expert "
                  "(fallback_top)")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger demo``."""
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), metavar="DIR",
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
    parser.add_argument("--episode-duration", "--time-limit", dest="time_limit", type=float,
                        default=DEFAULT_TIME_LIMIT, metavar="S",
                        help=f"simulated seconds per episode (default {DEFAULT_TIME_LIMIT:g}, "
                             "the goal-scoring experiment's; the paper's is 150; --time-limit: "
                             "the deprecated spelling)")
    parser.add_argument("--daemon-port", type=port, default=0, metavar="PORT",
                        help="loopback port of the demo's daemon, e.g. 7447 to watch it with "
                             "roger status (default 0: a free one, printed)")
    parser.add_argument("--sim-port", type=port, default=0, metavar="PORT",
                        help="loopback port of the demo's simulator (default 0: a free one)")
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
        from simulator.episodes import START_LOCATIONS, parse_locations

        args, console, out = self.args, self.console, self.out
        locations = parse_locations(args.locations)
        if not 0 <= args.test_location < len(START_LOCATIONS):
            raise ValueError(f"--test-location must be in 0..{len(START_LOCATIONS) - 1}")
        t_all = time.monotonic()
        console.rule("roger demo")
        console.print(f"demonstrations from locations {locations}, then the learned experts "
                      f"from location {args.test_location}, then the same experts merged per "
                      f"group, then the robot alone on its learned transitions (roger play), "
                      f"from each demonstrated location; output in {out}")
        summary: dict[str, Any] = {}
        live = {"mode": "learn+predict", "clock": "lockstep", "seed": args.seed,
                "queue_size": 100_000}
        with self._daemon("daemon", live, {"on_shutdown": True}, {"enabled": True},
                          ["--fresh"], robots=[{"id": "aibo", "model": FSM_MODEL}]) as daemon_ep:
            demo = self._episodes("demonstration", "demonstrator", locations, args.seed,
                                  daemon_ep, out / "demonstration")
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
                                  out / "transitioner")
            summary = {"demo": demo, "test": test, "updates": st.updates}
        summary["merged"] = self._merged_groups(locations)
        summary["autonomous"] = self._autonomous(locations)
        self._report(summary, time.monotonic() - t_all)
        return 0

    @contextlib.contextmanager
    def _daemon(self, name: str, daemon: dict[str, Any], checkpoint: dict[str, Any],
                recording: dict[str, Any], argv: list[str],
                robots: list[dict[str, Any]] | None = None) -> Iterator[str]:
        """``roger daemon`` (config ``OUT/NAME.toml``, log ``OUT/NAME.log``) on a free loopback
        port, with :attr:`client` connected: yields its endpoint; stopped at the end (SIGTERM,
        then exit 0 required)."""
        from roger_daemon.harness import Client, DaemonProcess, write_config
        from simulator.experiment.procs import CHILDREN, child_env, free_port

        out = self.out
        port = self.args.daemon_port or free_port()
        cfg = write_config(out / f"{name}.toml", port=port, workdir=out, daemon=daemon,
                           checkpoint={"every_updates": 0, "every_s": 0.0, **checkpoint},
                           recording=recording, robots=robots or [{"id": "aibo"}])
        with CHILDREN.spawning():  # a stop reaches it (procs.stop_children_on_signals)
            proc = DaemonProcess(cfg, args=argv, log=out / f"{name}.log", env=child_env())
            CHILDREN.add(proc.proc)
        endpoint = f"tcp/127.0.0.1:{port}"
        try:
            proc.wait_ready(120)
            self.client = Client(endpoint)
            self.client.wait_daemon(30)
            yield endpoint
            self.client.close()
            self.client = None
            code, _ = proc.terminate(60)
            if code != 0:
                raise RuntimeError(f"the daemon exited with {code}; see {out / name}.log")
        finally:
            if self.client is not None:
                self.client.close()
                self.client = None
            proc.kill()

    def _merged_groups(self, locations: list[int]) -> dict[str, Any]:
        """The learned experts merged per group, as a user would do it from a session of
        their own (README, the paper's experiment): ``roger replay LOG --merge-groups
        --save-checkpoint OUT/merged``, then ``roger daemon`` in predict mode resumed from that
        checkpoint, and the same transitioner, one episode from each of ``locations``."""
        from roger_daemon.recording import list_session_files
        from simulator.experiment.procs import ProcessGroup, roger_argv

        args, out = self.args, self.out
        logs = [sf.path for sf in list_session_files(out / "recordings", robot="aibo")]
        if len(logs) != 1:
            raise RuntimeError(f"expected one session log in {out / 'recordings'}, "
                               f"found {len(logs)}")
        command = ["replay", str(logs[0]), "--merge-groups", "--save-checkpoint",
                   str(out / "merged")]
        group = ProcessGroup(out)  # tracked: a stop reaches it; output in OUT/merge.log
        try:
            group.start("merge", roger_argv(*command))
            code = group.wait("merge", 600)
        finally:
            group.close()
        if code != 0:
            raise RuntimeError(f"roger replay --merge-groups exited with {code}; "
                               f"see {out / 'merge.log'}")
        serve = {"mode": "predict", "clock": "lockstep", "seed": args.seed}
        with self._daemon("daemon-merged", serve, {"dir": out / "merged", "on_shutdown": False},
                          {"enabled": False}, []) as endpoint:
            st = self._status(lambda s: s.mode == "predict", 10)
            test = self._episodes("experts merged per group + transitioner", "transitioner",
                                  locations, args.seed + 1, endpoint,
                                  out / "merged-transitioner")
        return {"test": test, "experts": int(st.experts), "command": "roger " + " ".join(command)}

    def _autonomous(self, locations: list[int]) -> dict[str, Any]:
        """The robot plays alone (:mod:`.demo_play`): the live daemon's checkpoint served in
        predict mode, ``roger play`` the only controller, one episode per location."""
        serve = {"mode": "predict", "clock": "lockstep", "seed": self.args.seed}
        with self._daemon("daemon-play", serve, {"dir": self.out / "checkpoints",
                                                 "on_shutdown": False},
                          {"enabled": False}, []) as endpoint:
            self._status(lambda s: s.mode == "predict", 10)
            test = self._episodes("learned transitions, no HCC (play)", "play", locations,
                                  self.args.seed + 1, endpoint, self.out / "play")
        return play_summary(test, self.out)

    def _episodes(self, title: str, role: str, locations: list[int], seed: int,
                  daemon_ep: str, workdir: Path) -> dict[str, Any]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

        from simulator.experiment.procs import (
            ProcessGroup,
            count_episodes,
            free_port,
            roger_argv,
        )

        args = self.args
        workdir.mkdir(parents=True, exist_ok=True)
        sim_port = args.sim_port or free_port()
        group = ProcessGroup(workdir)
        try:
            group.start("controller", roger_argv(
                *controller_argv(role, self.out), "--connect", f"tcp/127.0.0.1:{sim_port}",
                "--connect", daemon_ep, "--exit-when-done", "--idle-exit", "120",
                "--stats", str(workdir / "controller.json")))
            group.start("sim", roger_argv(
                "sim", "--clock", "lockstep", "--listen", f"tcp/127.0.0.1:{sim_port}",
                "--connect", daemon_ep, "--locations", ",".join(map(str, locations)),
                "--seed", str(seed), "--episode-duration", repr(float(args.time_limit)),
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

        from roger_daemon.config.models import load_model as load_daemon_model
        from roger_daemon.daemon.checkpoint import load_newest
        from simulator.experiment.demo_play import segmentation_figures

        out = self.out
        ck = load_newest(out / "checkpoints", "aibo")
        if ck is None:
            raise RuntimeError("the daemon wrote no checkpoint")
        model = load_daemon_model(ck.model)
        groups, seg, figs, mcap = segmentation_figures(out, model)
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
        t.add_row("commands chosen by", _chosen_by(ctl))
        merged = summary["merged"]
        m_eps = merged["test"]["episodes"]
        goals = sum(bool(e["success"]) for e in m_eps)
        t.add_row("experts merged per group + transitioner",
                  f"{goals} goals of {len(m_eps)} ({merged['experts']} experts, one per "
                  "group): " + ", ".join(
                      f"location {e['location']}: [{'green' if e['success'] else 'red'}]"
                      f"{e['outcome']}[/]" for e in m_eps))
        t.add_row("commands chosen by (merged)", _chosen_by(merged["test"]["controller"]))
        play_rows(t, summary["autonomous"])
        t.add_row("wall time", f"{wall:.0f} s")
        self.console.print(t)
        # paths and commands as plain lines, never wrapped, so that they can be copied
        import textwrap

        for text in (f"outcome {outcome}: {OUTCOME_MEANING.get(outcome, outcome)}",
                     f"merged per group: {MERGED_MEANING}",
                     f"roger play: {PLAY_MEANING}",
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
        print(f"merged:     {merged['command']}")
        for line in play_commands(out):
            print(line)
        write_json(out / "summary.json", {
            "experts": int(model.n_experts),
            "pairs": int(model.n_learned),
            "expert_labels": {str(k): v for k, v in sorted(groups.items())},
            "demonstrations": demo_eps,
            "test_episode": test,
            "transitioner": ctl,
            "merged": {"experts": merged["experts"], "episodes": m_eps,
                       "transitioner": merged["test"]["controller"],
                       "checkpoint_dir": str(out / "merged"), "command": merged["command"]},
            "autonomous": summary["autonomous"],
            "mcap": [str(p) for p in mcap],
            "checkpoint": str(ck.path),
            "figures": {k: str(v) for k, v in figs.items()},
            "wall_s": round(wall, 1),
        }, default=str)


def _chosen_by(ctl: dict[str, Any]) -> str:
    """The transitioner's counts of how each command was chosen, in a fixed order."""
    return ", ".join(f"{k} {ctl.get(k, 0)}"
                     for k in ("label", "fallback_top", "fallback_mean", "no_prediction"))


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

"""``roger replay FILE``: rebuild the learner offline and compare; or re-publish on Zenoh.

Exit codes: 0 ok; 1 ``--check`` found a mismatch beyond ``--tolerance`` (or nothing to
compare, or predictions the log cannot reproduce); 2 the session cannot be replayed as asked.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import Any

from roger_daemon.replay.compare import REL_TOL
from roger_daemon.tools.common import non_negative, seconds

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger replay``."""
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE",
                        help="session MCAP file(s); the other parts of a rotated session are "
                             "added automatically")
    parser.add_argument("--config", type=Path, metavar="CONFIG.toml",
                        help="take learner params from this config's [learner] table")
    parser.add_argument("--seed", type=int, help="model seed (default: the recorded one)")
    parser.add_argument("--robot", help="robot to replay (default: the recorded one)")
    parser.add_argument("--model", metavar="KIND",
                        help="the model kind (the daemon's [[robots]] model; default: the "
                             "recorded one); roger+fsm: also learn the transitions (a session "
                             "of plain ROGER gives the same experts and a checkpoint for roger "
                             "play, docs/autonomy.md)")
    parser.add_argument("--checkpoint", type=Path, metavar="FILE.npz",
                        help="the checkpoint the session resumed from (daemon checkpoint with "
                             "its queued pairs, or a plain state_dict .npz); or a daemon "
                             "checkpoint written during the session (e.g. the last one before "
                             "a crash): then only what the log holds after it is replayed")
    parser.add_argument("--save-checkpoint", type=Path, metavar="DIR",
                        help="write the replayed model as a daemon checkpoint into DIR (the "
                             "daemon's [checkpoint] dir), for the daemon to resume from")
    parser.add_argument("--merge-groups", action="store_true",
                        help="with --save-checkpoint: save ROGER's experts merged per group "
                             "(one expert per majority label, the experiment's 'merged "
                             "groups') instead of the replayed model; for a daemon in predict "
                             "mode driving the HCC transitioner. Needs the session from the "
                             "model's first pair")
    parser.add_argument("--split-gates", action="store_true",
                        help="with --save-checkpoint: save the model with each expert's gate "
                             "split where its inputs form clusters (no labels; one expert per "
                             "part, docs/goal-scoring.md) instead of the replayed model. Needs "
                             "the session from the model's first pair")
    parser.add_argument("--check", action="store_true",
                        help="exit 1 unless every recorded prediction is reproduced")
    parser.add_argument("--tolerance", type=non_negative, default=REL_TOL,
                        help="max relative error of any float allowed by --check (default "
                             f"{REL_TOL:g}, what two BLAS kernels stay inside; the structure "
                             "is always compared exactly)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    g = parser.add_argument_group("re-publish on Zenoh instead of replaying offline")
    g.add_argument("--publish", action="store_true", help="re-publish the recorded messages")
    g.add_argument("--speed", type=non_negative, default=1.0,
                   help="pace by log_time: 1 realtime, 0 as fast as possible")
    g.add_argument("--kinds", default="perception,action,command,episode,control",
                   help="message kinds to re-publish (comma-separated)")
    g.add_argument("--wait", type=seconds, default=2.0, metavar="S",
                   help="wait up to S seconds for subscribers before publishing (default 2)")
    from roger_daemon.recording import zenoh_net

    zenoh_net.add_arguments(parser)


def _session_files(files: list[Path]) -> list[Path]:
    from roger_daemon.recording import files as sfiles

    if len(files) != 1:
        return files
    sf = sfiles.parse_name(files[0])
    if sf is None:
        return files
    parts = [f.path for f in sfiles.list_session_files(files[0].parent, robot=sf.robot)
             if f.session_id == sf.session_id]
    return parts or files


def _config(path: Path, robot: str, dims: Any) -> tuple[dict[str, Any], int, str | None]:
    """(learner params, seed, model kind) of ``robot`` in a daemon config file.

    Read with the daemon's own parser (per-robot overrides included); a file it rejects
    raises ``ValueError``. A robot the config does not list is resolved as the daemon would
    resolve it listed with the log's ``dims`` (:func:`roger_daemon.config.robot_config`: the
    ``[learner]`` table and ``[daemon] seed``); its model kind is then the log's.
    """
    from roger_daemon.config import load_config, robot_config

    cfg = load_config(path)
    listed = any(r.id == robot for r in cfg.robots)
    if dims is None and not listed:
        raise ValueError(f"{path} does not list robot {robot!r} and the log names no dims")
    r = robot_config(cfg, robot, dims)
    return dict(r.params.to_mapping()), int(r.seed), str(r.model) if listed else None


def run(args: argparse.Namespace) -> int:
    """Replay (or re-publish) and report."""
    from roger_daemon.recording.mcapio import not_an_mcap_file

    files = _session_files(list(args.files))
    if args.model is not None:
        from roger_daemon.config.models import MODELS

        if args.model not in MODELS:
            print(f"roger replay: --model must be one of {', '.join(MODELS)}, got "
                  f"{args.model!r}", file=sys.stderr)
            return 2
    for f in files:
        if why := not_an_mcap_file(f):
            print(f"roger replay: {why}", file=sys.stderr)
            return 2
    if args.save_checkpoint and (why := _not_a_directory(args.save_checkpoint)):
        print(f"roger replay: --save-checkpoint must be a directory (the daemon's [checkpoint] "
              f"dir), got {str(args.save_checkpoint)!r}: {why}", file=sys.stderr)
        return 2
    if args.publish:
        if args.robot:
            from roger_daemon.recording.session_read import robot_absent

            if why := robot_absent(files, args.robot):
                print(f"roger replay: {why}", file=sys.stderr)
                return 2
        return _publish(args, files)
    return _replay(args, files)


def _not_a_directory(path: Path) -> str:
    """Why ``path`` cannot be (made) a directory ("" if it is one or can be created)."""
    for p in (path, *path.parents):
        if p.exists():
            return "" if p.is_dir() else (
                "it is a file" if p == path else f"{str(p)!r} is a file")
    return ""


def _replay(args: argparse.Namespace, files: list[Path]) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    from roger_daemon.recording.catchup import CatchUpError
    from roger_daemon.recording.session_read import read_timeline
    from roger_daemon.replay.session import (
        ReplayError,
        load_checkpoint,
        replay_timeline,
        resume_timeline,
    )

    err = Console(stderr=True)
    params: dict[str, Any] | None = None
    seed: int | None = None
    kind: str | None = args.model
    try:
        tl = read_timeline(files, robot=args.robot)
        if args.config:
            params, seed, cfg_kind = _config(args.config, tl.robot, tl.dims)
            kind = kind or cfg_kind
        if args.seed is not None:
            seed = args.seed
        initial: Any = None
        queued: list[Any] = []
        ck_meta = None
        notes: list[str] = []
        if args.checkpoint:
            initial, queued, ck_meta = load_checkpoint(args.checkpoint)
            learned = int(initial.n_learned)
            if ck_meta is not None and learned != tl.segments[0].start_updates:
                # a checkpoint taken during the session: checkpoint + the log's tail
                tl2, notes = resume_timeline(tl, files, learned=learned, meta=ck_meta,
                                             queued=queued)
                if tl2 is tl:
                    initial, queued = None, []
                tl, queued = tl2, []
        total = sum(len(s.pairs) for s in tl.segments)
        with Progress(
            "[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
            TimeElapsedColumn(), console=err, transient=True,
            disable=args.no_progress or args.json,
        ) as prog:
            task = prog.add_task("replaying", total=total)
            res = replay_timeline(
                tl, params=params, seed=seed, model_kind=kind, initial_model=initial,
                initial_pairs=queued,
                progress=lambda n: prog.advance(task, n),
            )
        res.warnings.extend(notes)
        saved = ""
        merged = _served(args, res)
        if args.save_checkpoint:
            saved = str(_save(merged or res, args.save_checkpoint,
                              args.checkpoint if initial is not None else None, queued))
    except (ReplayError, CatchUpError, ValueError) as exc:
        print(f"roger replay: {exc}", file=sys.stderr)
        return 2
    summary = res.summary(args.tolerance)
    if saved:
        summary["saved_checkpoint"] = saved
    if merged is not None:  # what the checkpoint holds: one expert per group, or per part
        key = "merged_groups" if args.merge_groups else "split_gates"
        summary[key] = {str(k): v for k, v in sorted(merged.expert_labels.items())}
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        _print_summary(summary, res)
        if merged is not None and args.merge_groups:
            print(f"merged:       {len(merged.expert_labels)} experts, one per group "
                  f"({', '.join(sorted(merged.expert_labels.values()))}); saved, not the "
                  "replayed model")
        elif merged is not None:
            print(f"split gates:  {merged.n_experts} experts, one per part of "
                  f"{res.n_experts} experts' gates; saved, not the replayed model")
    if not args.check:
        return 0
    if not res.diffs:
        print("roger replay --check: the log has no predictions to compare", file=sys.stderr)
        return 1
    return 0 if res.ok(args.tolerance) else 1


def _served(args: argparse.Namespace, res: Any) -> Any:
    """The model ``--merge-groups`` or ``--split-gates`` saves instead of the replayed one
    (:mod:`roger_daemon.replay.served`), or None."""
    from roger_daemon.replay import served
    from roger_daemon.replay.session import ReplayError

    if args.merge_groups and args.split_gates:
        raise ReplayError("--merge-groups and --split-gates: choose one")
    for flag, make in (("merge_groups", served.merged), ("split_gates", served.split)):
        if getattr(args, flag):
            if not args.save_checkpoint:
                raise ReplayError(f"--{flag.replace('_', '-')} needs --save-checkpoint DIR")
            return make(res)
    return None


def _save(res: Any, directory: Path, checkpoint: Path | None, queued: list[Any]) -> Path:
    """Write the replayed model as a daemon checkpoint (labels from the checkpoint, if any)."""
    from roger_daemon.replay.session import save_checkpoint

    vocab: list[str] = []
    codes: list[int] = []
    if checkpoint is not None:
        from roger_daemon.daemon.checkpoint import CheckpointError, read_checkpoint
        from roger_daemon.daemon.robot_state import RobotState

        try:
            state = RobotState.from_arrays(read_checkpoint(checkpoint).daemon)
            vocab, codes = state.vocab, state.codes.tolist()
        except (CheckpointError, KeyError):
            pass  # a plain state_dict: the labels of its pairs are unknown
    return save_checkpoint(res, directory, base_vocab=vocab, base_codes=codes,
                           queued_labels=[q.label for q in queued])


def _print_summary(s: dict[str, Any], res: Any) -> None:
    print(f"files:        {', '.join(s['files'])}")
    print(f"robot:        {s['robot']}   model: {s['model']}   seed: {s['seed']}")
    print(f"learned:      {s['pairs_learned']} pairs ({s['segments']} segment(s)); "
          f"n_learned {s['n_learned']}")
    sizes = ", ".join(f"{k}:{v}" + (f"({s['expert_labels'][k]})" if s["expert_labels"].get(k)
                                     else "") for k, v in s["expert_sizes"].items())
    print(f"experts:      {s['n_experts']}  [{sizes}]")
    print(f"predictions:  {s['predictions_compared']} compared, "
          f"{s['predictions_unreplayable']} unreplayable")
    mm = s["max_abs_diff_multimap"]
    print(f"max |diff|:   mean {s['max_abs_diff_mean']:.3g}  var {s['max_abs_diff_var']:.3g}  "
          f"multimap {mm if isinstance(mm, str) else format(mm, '.3g')}")
    rel = s["max_rel_err"]
    print(f"max rel err:  {rel if isinstance(rel, str) else format(rel, '.3g')} "
          f"(tolerance {s['tolerance']:g})")
    print(f"mismatches:   {s['mismatches']} beyond {s['tolerance']:g} (expert "
          f"{s['expert_mismatches']}, multimap ids {s['multimap_id_mismatches']}, sizes "
          f"{s['size_mismatches']}; labels {s['label_mismatches']} reported only)")
    div = s["first_divergence"]
    if div:
        print(f"diverges:     tick {div['tick']} (update {div['updates']}, segment "
              f"{div['segment']}): {div['what']}")
        st = div["first_structure_divergence"]
        if st and st["tick"] != div["tick"]:
            print(f"structure:    first differs at tick {st['tick']} (update {st['updates']}): "
                  f"{st['what']}")
        if st and st["closest_decision"]:
            c = st["closest_decision"]
            print(f"decision:     closest before it: {c['kind']} at update {c['updates']}, "
                  f"margin {c['margin']:.3g} ("
                  + ("round-off of another BLAS kernel can flip it" if st["round_off_can_explain"]
                     else "too wide for round-off: the learner or its inputs differ") + ")")
    if s["first_mismatch"]:
        print(f"first:        {s['first_mismatch']}")
    if s["invalid_messages"]:
        print(f"invalid:      {s['invalid_messages']}")
    for w in s["warnings"]:
        print(f"warning:      {w}")
    if s.get("saved_checkpoint"):
        print(f"checkpoint:   {s['saved_checkpoint']} ({s['n_learned']} updates)")
    print("result:       " + ("OK, " if s["ok"] else "") + s["verdict"])


def _publish(args: argparse.Namespace, files: list[Path]) -> int:

    from roger_daemon.recording import zenoh_net
    from roger_daemon.recording.publish import publish_log
    from roger_daemon.zenoh_session import open_session, settings_from_args

    stop = {"flag": False}

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop["flag"] = True

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    try:
        with open_session(settings_from_args(args)) as session:
            if not zenoh_net.reached(session, args, "roger replay --publish"):
                return 1
            st = publish_log(session, files, speed=args.speed, kinds=kinds, robot=args.robot,
                             should_stop=lambda: stop["flag"], wait_subscribers_s=args.wait)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    out = {"published": st.published, "skipped": st.skipped, "by_topic": st.by_topic,
           "wall_s": round(st.wall_s, 3), "log_span_s": round(st.log_span_s, 3),
           "max_late_s": round(st.max_late_s, 4), "interrupted": stop["flag"],
           "subscribers_matched": st.subscribers_matched}
    print(json.dumps(out, indent=2, sort_keys=True) if args.json else
          f"published {st.published} messages in {st.wall_s:.2f} s (log span "
          f"{st.log_span_s:.2f} s, speed {args.speed:g}); skipped {st.skipped}")
    return 0

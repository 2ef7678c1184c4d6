"""Replay and checkpoints: start from a daemon checkpoint (:func:`load_checkpoint`,
:func:`resume_timeline`) and save the replayed model as one (:func:`save_checkpoint`)."""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from roger_daemon.daemon.checkpoint_meta import CheckpointMeta, Counters, LearnerSpec
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.recording.timeline import LearnedPair, Segment, Timeline
from roger_daemon.replay.result import Model, ReplayError, ReplayResult

__all__ = ["load_checkpoint", "resume_timeline", "save_checkpoint"]


def load_checkpoint(path: str | Path
                    ) -> tuple[Model, list[LearnedPair], CheckpointMeta | None]:
    """``(model, queued pairs, meta)`` from a daemon checkpoint (``roger_daemon.daemon.checkpoint``;
    its queue read by :class:`~roger_daemon.daemon.robot_state.RobotState`), or from a plain
    ``.npz`` of a ``state_dict()`` (no queue, no meta: ``None``). Never unpickles.  Raises
    :class:`ReplayError` naming the file when the checkpoint's daemon arrays do not fit
    together."""
    from roger_daemon.config.models import load_model
    from roger_daemon.daemon.checkpoint import CheckpointError, read_checkpoint

    try:
        ck = read_checkpoint(Path(path))
    except CheckpointError as exc:
        return _plain_state_dict(Path(path), str(exc)), [], None
    model: Model = load_model(ck.model)
    try:
        state = RobotState.from_arrays(ck.daemon)
    except KeyError:  # an older checkpoint without a queue
        return model, [], ck.meta
    except ValueError as exc:  # daemon arrays that do not fit together
        raise ReplayError(f"checkpoint {path}: {exc}") from None
    start = int(model.n_learned)
    pairs = [LearnedPair(start + i, p.tick, p.x, p.y, state.label(p.label), 0)
             for i, p in enumerate(state.queue)]
    return model, pairs, ck.meta


def _plain_state_dict(path: Path, why: str) -> Model:
    """The model of a plain ``.npz`` of a ``state_dict()``; :class:`ReplayError` naming the
    file when it is not one (a text file, a damaged archive, arrays of no model)."""
    from roger_daemon.config.models import load_model

    what = f"checkpoint {path} is neither a daemon checkpoint ({why}) nor a state_dict .npz"
    if not path.is_file():
        raise ReplayError(f"checkpoint {path}: " + ("not a file" if path.exists() else
                                                     "no such file"))
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # numpy: "pickled data"
        raise ReplayError(f"checkpoint {path} is not an .npz archive (expected a daemon "
                          "checkpoint or a plain state_dict .npz)") from None
    if not isinstance(z, np.lib.npyio.NpzFile):  # a single .npy array
        raise ReplayError(f"{what} (one array, not an archive of a model's arrays)")
    try:
        with z:
            model: Model = load_model({k: z[k] for k in z.files})
            return model
    except (KeyError, ValueError, TypeError, zipfile.BadZipFile) as exc:
        raise ReplayError(f"{what} ({exc})") from None


def resume_timeline(
    tl: Timeline,
    files: Sequence[str | Path],
    *,
    learned: int,
    meta: CheckpointMeta,
    queued: Sequence[LearnedPair] = (),
) -> tuple[Timeline, list[str]]:
    """The part of a session after a checkpoint taken *during* it (a crash's last checkpoint).

    The result has one segment starting at ``learned``: the checkpoint's queued pairs and the
    pairs logged after them (log-tail catch-up, checked against the checkpoint's last learned
    tick), with the recorded predictions computed from that point on. Replay it with the
    checkpoint's model as ``initial_model`` (no ``initial_pairs``: they are in the segment).
    Returns the original timeline and a warning when the history restarted after the
    checkpoint (a reset): that part replays without it.
    """
    from roger_daemon.recording.catchup import log_tail

    same = meta.session_id == tl.info.session_id
    tail = log_tail(
        list(files), learned=learned, robot=tl.robot, dims=tl.dims,
        last_tick=meta.counters.last_learned_tick,
        from_session=tl.info.session_id if same and tl.info.session_id else None,
        segment=meta.session_segment if same else 0,
        queue=queued,
    )
    if tail.fresh:
        return tl, ["the session reset its model after the checkpoint: the model after the "
                    "reset is replayed from a fresh model, without the checkpoint"]
    k = meta.session_segment if same else len(tl.segments) - 1
    k = min(max(k, 0), len(tl.segments) - 1)
    preds = [p for p in tl.segments[k].predictions if p.updates >= learned]
    seg = Segment(start_updates=learned, after_reset=False, pairs=list(tail.pairs),
                  predictions=preds,
                  digests=[c for c in tl.segments[k].digests if c.updates >= learned])
    notes = list(tail.notes)
    return replace(tl, segments=[seg]), notes


def save_checkpoint(
    res: ReplayResult,
    directory: str | Path,
    *,
    base_vocab: Sequence[str] = (),
    base_codes: Sequence[int] = (),
    queued_labels: Sequence[str] = (),
    keep: int = 5,
) -> Path:
    """Write the replayed model as a daemon checkpoint in ``directory`` (the daemon's
    ``[checkpoint] dir``), so that ``roger daemon`` resumes from it.

    ``base_vocab``/``base_codes`` are the labels of the pairs the initial model had learned
    (a daemon checkpoint's ``label_vocab``/``label_codes``) and ``queued_labels`` those of its
    queued pairs given as ``initial_pairs``; pairs without a known label get the empty label.
    The checkpoint names the session and segment it stands at, so the daemon's start-up
    recovery only re-learns what was logged after the replayed pairs.
    """
    from roger_daemon.daemon.checkpoint import write_checkpoint

    if res.model is None:
        raise ReplayError("nothing was replayed: no model to save")
    if res.learn_errors:
        raise ReplayError("the learner rejected some pairs; their labels cannot be lined up")
    model = res.model
    n = int(model.n_learned)
    state = RobotState.from_labels([*queued_labels, *res.labels], vocab=base_vocab)
    own = state.codes.tolist()[-n:] if n else []
    earlier = n - len(own)  # pairs the initial model had learned
    base = [int(c) for c in base_codes][:earlier]
    if earlier > len(base):  # their labels are unknown: the empty label
        unknown = RobotState.from_labels([""], vocab=state.vocab)
        state.vocab = unknown.vocab
        base += [int(unknown.codes[0])] * (earlier - len(base))
    state.codes = np.array(base + own, dtype=np.int32)
    seg_no = len(res.timeline.segments) - 1
    last = res.pairs[-1].tick if res.pairs else None
    d = res.timeline.dims
    assert d is not None
    daemon = state.to_arrays(d)
    meta = CheckpointMeta(
        reason="replay", updates=n, x_dim=d.x, y_dim=d.y,
        learner=LearnerSpec(res.model_kind, res.seed, res.params),
        counters=Counters(last_learned_tick=last, last_tick=last or 0),
        session_id=res.info.session_id, session_segment=seg_no,
        replayed_from=tuple(str(p) for p in res.files),
    )
    path, _ = write_checkpoint(Path(directory), res.robot, dict(model.state_dict()), daemon, meta,
                               keep=keep)
    return path

"""LeRobot's ACT and Diffusion Policy on ROGER's demonstrations: configure, train, act.

The torch/LeRobot side of ``roger experiment peers`` (docs/peers.md). It needs the ``peers``
extra (``make venv-peers``: LeRobot 0.4.4 with torch 2.9.1 in ``.venv-peers``); every
import of torch or LeRobot is inside a function, so the module itself imports anywhere (the
test suite's doctest collection, mypy in the main venv).

* The policies are LeRobot's own classes (``make_policy_config``, ``make_policy``,
  ``make_pre_post_processors``), trained by a loop that does what ``lerobot-train`` does per
  step (preprocess, ``policy.forward``, backward, gradient clipping at the optimizer preset's
  ``grad_clip_norm``, the optimizer and scheduler presets), on a ``LeRobotDataset`` read from
  the directory ROGER's LeRobot v3 export wrote, with the ``delta_timestamps`` LeRobot
  resolves from the policy's config.
* Inputs: the 23-D perception only, split the way LeRobot's policies name state:
  ``observation.environment_state`` = the six colour blobs (entries 0-17: what the camera
  sees), ``observation.state`` = head and tail joints (18-22). Both policies need an image or
  an environment state, and Diffusion Policy needs ``observation.state`` as well
  (``DiffusionConfig.validate_features``, ``DiffusionModel``). No images.
* :data:`SCALED`: the only changes from LeRobot's defaults, each with its reason.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["ENV_KEY", "POLICIES", "SCALED", "STATE_KEY", "PolicyController", "Trained",
           "available", "train_policy"]

POLICIES = ("act", "diffusion")
STATE_KEY = "observation.state"
ENV_KEY = "observation.environment_state"
#: perception[:SPLIT] = colour blobs (environment), perception[SPLIT:] = head and tail joints
SPLIT = 18
#: The dataset's repo id (local only: LeRobotDataset reads ``root`` and never the hub).
REPO_ID = "roger/goal-scoring"

#: Changes from LeRobot's default config per policy, and why (docs/peers.md, "Settings").
#: ACT: none. Diffusion Policy: the U-Net of Chi et al.'s low-dimensional (state) tasks,
#: (256, 512, 1024) instead of LeRobot's image-task (512, 1024, 2048) - a 23-D state is the
#: data size the smaller net was made for - and DDIM with 10 denoising steps at inference
#: instead of DDPM's 100, so that one chunk costs tens of ms on one CPU core, not seconds.
SCALED: dict[str, dict[str, Any]] = {
    "act": {},
    "diffusion": {"down_dims": (256, 512, 1024), "noise_scheduler_type": "DDIM",
                  "num_inference_steps": 10},
}


def available() -> str:
    """"" if torch and LeRobot import here, else why not (for a skip or an exit message)."""
    try:
        import lerobot  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        return (f"LeRobot is not installed here ({exc}); `make venv-peers` builds .venv-peers "
                "with the peers extra (docs/peers.md)")
    return ""


@dataclass
class Trained:
    """A trained policy with its processors and what training cost."""

    name: str
    policy: Any
    preprocessor: Any
    postprocessor: Any
    steps: int
    batch_size: int
    samples: int  # frames a training sample may start at
    episodes: int
    train_cpu_s: float
    train_wall_s: float
    losses: list[float] = field(default_factory=list)
    config: dict[str, Any] = field(default_factory=dict)

    def parameters(self) -> int:
        """Number of parameters of the policy."""
        return int(sum(p.numel() for p in self.policy.parameters()))

    def save(self, directory: Path) -> int:
        """``policy.save_pretrained`` and the processors into ``directory`` (safetensors and
        JSON, LeRobot's own format); returns the bytes written."""
        directory.mkdir(parents=True, exist_ok=True)
        self.policy.save_pretrained(directory)
        self.preprocessor.save_pretrained(directory)
        self.postprocessor.save_pretrained(directory)
        return sum(f.stat().st_size for f in directory.rglob("*") if f.is_file())


def policy_config(name: str, overrides: dict[str, Any] | None = None) -> Any:
    """LeRobot's config of policy ``name`` on CPU, with :data:`SCALED` and ``overrides``, and
    the two state inputs (module docstring)."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import make_policy_config

    if name not in POLICIES:
        raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {name!r}")
    cfg = make_policy_config(name, device="cpu", push_to_hub=False,
                             **{**SCALED[name], **(overrides or {})})
    cfg.input_features = {
        STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(23 - SPLIT,)),
        ENV_KEY: PolicyFeature(type=FeatureType.ENV, shape=(SPLIT,)),
    }
    return cfg


def split_stats(stats: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The dataset's statistics with ``observation.state`` split as the inputs are."""
    out = {k: dict(v) for k, v in stats.items() if k != STATE_KEY}
    whole = stats[STATE_KEY]
    out[ENV_KEY] = {k: _cut(v, slice(0, SPLIT)) for k, v in whole.items()}
    out[STATE_KEY] = {k: _cut(v, slice(SPLIT, None)) for k, v in whole.items()}
    return out


def _cut(v: Any, s: slice) -> Any:
    a = np.asarray(v)
    return a[..., s] if a.ndim and a.shape[-1] == 23 else a


def split_batch(batch: dict[str, Any]) -> dict[str, Any]:
    """A dataset batch (or one observation) with the perception split into the two inputs;
    keys the policies do not read are dropped."""
    x = batch[STATE_KEY]
    out = {ENV_KEY: x[..., :SPLIT], STATE_KEY: x[..., SPLIT:]}
    for k in ("action", "action_is_pad", f"{STATE_KEY}_is_pad"):
        if k in batch:
            out[k] = batch[k]
    if f"{STATE_KEY}_is_pad" in batch:
        out[f"{ENV_KEY}_is_pad"] = batch[f"{STATE_KEY}_is_pad"]
    return out


def _sample_indices(ds: Any, starts: npt.NDArray[np.int64] | None, drop_last: int
                    ) -> npt.NDArray[np.int64]:
    """Positions in ``ds`` a sample may start at: the frames whose absolute index is in
    ``starts`` (all if None), minus each episode's last ``drop_last`` frames (LeRobot's
    ``drop_n_last_frames``, as its ``EpisodeAwareSampler``)."""
    absolute = np.asarray(ds.hf_dataset["index"], dtype=np.int64).reshape(-1)
    episode = np.asarray(ds.hf_dataset["episode_index"], dtype=np.int64).reshape(-1)
    ok = np.ones(absolute.size, dtype=bool) if starts is None else np.isin(absolute, starts)
    if drop_last > 0:
        last = np.r_[episode[1:] != episode[:-1], True]
        ends = np.flatnonzero(last)
        for e in ends:
            ok[max(0, e - drop_last + 1):e + 1] = False
    return np.flatnonzero(ok).astype(np.int64)


def train_policy(name: str, root: Path, *, steps: int, batch_size: int, seed: int,
                 episodes: Sequence[int] | None = None,
                 starts: npt.NDArray[np.int64] | None = None,
                 overrides: dict[str, Any] | None = None,
                 progress: Callable[[int, float], None] | None = None) -> Trained:
    """Train LeRobot's ``name`` on the dataset in ``root`` for ``steps`` optimizer steps.

    ``episodes``: the dataset episodes to use (None: all); ``starts``: the absolute frame
    indices a sample may start at (None: every frame; the action chunk after a start is read
    from the demonstration's following frames either way). ``progress(step, loss)`` is
    called every 100 steps. CPU time is the process's (all threads) over the loop.
    """
    import torch
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    torch.manual_seed(seed)
    cfg = policy_config(name, overrides)
    meta = LeRobotDatasetMetadata(REPO_ID, root=root)
    ds = LeRobotDataset(REPO_ID, root=root, episodes=list(episodes) if episodes else None,
                        delta_timestamps=resolve_delta_timestamps(cfg, meta))
    stats = split_stats(meta.stats)
    policy = make_policy(cfg, ds_meta=meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    optimizer_cfg = cfg.get_optimizer_preset()
    optimizer = optimizer_cfg.build(policy.get_optim_params())
    scheduler_cfg = cfg.get_scheduler_preset()
    if scheduler_cfg is not None and getattr(scheduler_cfg, "num_warmup_steps", None):
        # a 500-step warm-up (Diffusion Policy's preset) is scaled with a shorter budget
        scheduler_cfg.num_warmup_steps = min(scheduler_cfg.num_warmup_steps, steps // 10)
    scheduler = scheduler_cfg.build(optimizer, steps) if scheduler_cfg is not None else None
    idx = _sample_indices(ds, starts, int(getattr(cfg, "drop_n_last_frames", 0)))
    gen = torch.Generator().manual_seed(seed)
    loader = torch.utils.data.DataLoader(
        ds, batch_size=batch_size, num_workers=0, drop_last=False,
        sampler=torch.utils.data.SubsetRandomSampler(idx.tolist(), generator=gen))
    losses: list[float] = []
    policy.train()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    it = iter(loader)
    for step in range(steps):
        try:
            batch = next(it)
        except StopIteration:
            it = iter(loader)
            batch = next(it)
        loss, _ = policy.forward(pre(split_batch(batch)))
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), optimizer_cfg.grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        if scheduler is not None:
            scheduler.step()
        losses.append(float(loss.item()))
        if progress is not None and (step + 1) % 100 == 0:
            progress(step + 1, float(np.mean(losses[-100:])))
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    policy.eval()
    chosen = {k: getattr(cfg, k) for k in _REPORTED if hasattr(cfg, k)}
    return Trained(name, policy, pre, post, steps, batch_size, int(idx.size),
                   len(episodes) if episodes else meta.total_episodes, round(cpu, 2),
                   round(wall, 2), losses, _plain(chosen))


#: Config fields results.json reports per policy (LeRobot's names).
_REPORTED = ("chunk_size", "n_action_steps", "n_obs_steps", "horizon", "dim_model",
             "n_encoder_layers", "n_decoder_layers", "use_vae", "kl_weight", "down_dims",
             "noise_scheduler_type", "num_train_timesteps", "num_inference_steps",
             "optimizer_lr", "optimizer_weight_decay", "drop_n_last_frames")


def _plain(d: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


class PolicyController:
    """A trained policy acting alone in the simulator: each tick the perception, split into
    the policy's two inputs, through the preprocessor, ``select_action`` (LeRobot's action
    queue: a new chunk when the queue is empty) and the postprocessor. No HCC, no subtask.

    ``times_s`` keeps every tick's wall time of that path (the inference time per tick)."""

    def __init__(self, trained: Trained, seed: int = 0) -> None:
        self.trained = trained
        self.seed = seed
        self.episodes = 0
        self.times_s: list[float] = []
        self.counts: dict[str, int] = {}

    def reset(self) -> None:
        """Start an episode: LeRobot's queues emptied, the sampling noise reseeded."""
        import torch

        torch.manual_seed(self.seed + self.episodes)
        self.episodes += 1
        self.trained.policy.reset()

    def act(self, x: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], str]:
        """One tick: the policy's action for perception ``x``."""
        import torch

        t0 = time.perf_counter()
        obs = {STATE_KEY: torch.as_tensor(np.asarray(x, dtype=np.float32))}
        with torch.inference_mode():
            action = self.trained.policy.select_action(self.trained.preprocessor(split_batch(obs)))
            action = self.trained.postprocessor(action)
        y = np.asarray(action, dtype=np.float64).reshape(-1)
        self.times_s.append(time.perf_counter() - t0)
        if not np.all(np.isfinite(y)):
            from simulator.experiment.inprocess import hold_command

            self.counts["non_finite"] = self.counts.get("non_finite", 0) + 1
            y = hold_command(np.asarray(x, dtype=np.float64))
        return y, ""

"""Train a demonstration-conditioned policy by behaviour cloning (paper, appendix
"Training details").

Read top to bottom: config -> data -> model -> (resume) -> epochs -> final checkpoint.

- RMSprop; an epoch walks every base environment once (shuffled); an iteration draws from one
  environment the recipe's demonstrations + agent successes (`PolicyConfig.recipe`).
- Actions are standardised with statistics of the training rollouts (see `DCPolicy`).
- After every epoch, `<out>/last.pt` holds model, optimizer, RNG state, epoch and the log,
  so an interrupted run resumes where it stopped and ends with the same weights;
  `<out>/train_log.json` holds the per-epoch losses. The result is `<out>/policy.pt`.
- DCT and SCAN model time step by step, so they see every rollout frame (trained on subsampled
  episodes they would meet another frame rate online); their demonstrations are thinned
  (`PolicyConfig.demo_frames`) identically in training and online.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import random
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader
from tqdm import tqdm

from aed_models.checkpoint import load_checkpoint, save_checkpoint
from aed_models.data import Composition, EnvironmentIterations, EnvironmentSampler, load_episodes
from aed_models.layout import RunLayout
from aed_models.policies import FAMILY, POLICIES, PolicyConfig, make_policy
from aed_models.recipe import PolicyRecipe, Profile, check_profile
from aed_models.train.frame_features import frame_features
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)


@dataclass
class TrainPolicyConfig(PolicyRecipe):
    """Behaviour cloning of one policy on one task's base-split collection: the recipe's fields
    (epochs, lr, weight_decay, max_frames, composition, rollout_frames, shift) and what to train.
    Build it with `from_preset`, which fills the recipe of (policy, profile, task) and the
    paths of the runs layout.

    Args:
        task: task name (e.g. PressButton).
        policy: naive_dc, dct or scan.
        profile: the preset of the model's sizes and of the recipe (mini, paper, demo).
        data: collection folder.
        out: output folder (checkpoints and log).
        num_envs: use the first N base environments (0: all).
        seed: seeds the model, the draws and the augmentation.
        resume: continue from <out>/last.pt when it exists.
        progress: show a progress bar.
        device: torch device.
        workers: DataLoader worker processes (0 = read in the main process).
        encoder: the scene encoder checkpoint a `frozen_encoder` policy starts from.
    """

    task: str
    policy: str
    profile: Profile
    data: Path
    out: Path
    num_envs: int = 0
    seed: int = 0
    resume: bool = True
    progress: bool = True
    device: str = "cpu"
    workers: int = 0
    encoder: Path = Path("runs/PressButton/encoder/encoder.pt")

    def __post_init__(self) -> None:
        super().__post_init__()
        POLICIES.check(self.policy)
        check_profile(self.profile)
        if self.num_envs < 0 or self.workers < 0:
            raise ValueError(f"num_envs={self.num_envs}, workers={self.workers}: must be >= 0")
        self.data, self.out, self.encoder = Path(self.data), Path(self.out), Path(self.encoder)

    @classmethod
    def from_preset(
        cls,
        task: str = "PressButton",
        policy: str = "naive_dc",
        profile: str = "mini",
        runs: Path = Path("runs"),
        **overrides: Any,
    ) -> TrainPolicyConfig:
        """The recipe of (policy, profile, task), the layout's paths under `runs`, then
        `overrides`."""
        layout = RunLayout(runs)
        preset = {
            **dataclasses.asdict(POLICIES.recipe(policy, profile, task)),
            "task": task,
            "policy": policy,
            "profile": profile,
            "data": layout.data(task, "base"),
            "out": layout.policy(task, policy).parent,
            "encoder": layout.encoder(task),
        }
        return cls(**{**preset, **overrides})

    def recipe(self) -> PolicyRecipe:
        return PolicyRecipe(
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(PolicyRecipe)}
        )


# What a resumed training must share with the one it continues (its epochs may grow).
RESUME_FIELDS = (
    "task",
    "policy",
    "detector",
    "profile",
    "data",
    "num_envs",
    "seed",
    "lr",
    "weight_decay",
    "max_frames",
    "composition",
    "rollout_frames",
    "shift",
    "augment",
)


def check_task(episodes: list, task: str, data: Path) -> None:
    """Refuse to train a task's model on another task's episodes."""
    tasks = sorted({e.task for e in episodes})
    if tasks != [task]:
        raise ValueError(
            f"{data}: episodes of {', '.join(tasks) or 'no task'}, not of task={task!r}"
        )


def data_key(episodes: list) -> str:
    """Identifies the training episodes (shard, trajectory, seed, length of each)."""
    rows = sorted(f"{e.path.name}/{e.traj}/{e.seed}/{e.length}" for e in episodes)
    return hashlib.sha256("\n".join(rows).encode()).hexdigest()[:16]


def check_same_training(
    last_path: Path, extra: dict[str, Any], train_config: dict[str, Any], key: str
) -> None:
    """Refuse to resume a training under other data or settings, naming the first difference."""
    stored = extra.get("train_config", {})
    for name in RESUME_FIELDS:
        if name in stored and name in train_config and stored[name] != train_config[name]:
            raise ValueError(
                f"{last_path}: trained with {name}={stored[name]!r}, this run asks "
                f"{train_config[name]!r}; pass --no-resume to start over, or another --out"
            )
    if extra.get("data_key", key) != key:
        raise ValueError(
            f"{last_path}: trained on other episodes than {train_config.get('data')} holds now; "
            "pass --no-resume to start over, or another --out"
        )


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


def select_environments(episodes: list, num_envs: int) -> list:
    """The episodes of the first `num_envs` environments (by index; 0: all)."""
    if not num_envs:
        return episodes
    keep = set(sorted({e.env_index for e in episodes})[:num_envs])
    return [e for e in episodes if e.env_index in keep]


def trained_on(episodes: list) -> dict[str, Any]:
    """What a checkpoint records of its training data: the split and environment indices, so
    that evaluation and calibration can refuse to score a model where it trained."""
    return {"train_split": "base", "train_envs": sorted({int(e.env_index) for e in episodes})}


def rollout_actions(episodes: list) -> torch.Tensor:
    """Every action of the agent successes (what the policy is trained to output): (M, 4)."""
    by_file: dict[Path, list[str]] = defaultdict(list)
    for ref in episodes:
        if ref.role == "agent_success":
            by_file[ref.path].append(ref.traj)
    actions = []
    for path, trajs in by_file.items():
        with h5py.File(path, "r") as h5:
            actions += [h5[traj]["actions"][()] for traj in trajs]
    if not actions:
        raise ValueError("no agent_success episodes: nothing to imitate")
    return torch.from_numpy(np.concatenate(actions).astype(np.float32))


def random_shift(frames: torch.Tensor, shift: int, generator: torch.Generator) -> torch.Tensor:
    """Shift each sequence (B, L, C, H, W) by up to +-`shift` px, edges replicated (DrQ-style)."""
    if shift == 0:
        return frames
    b, length, c, h, w = frames.shape
    padded = F.pad(frames.flatten(0, 1), (shift,) * 4, mode="replicate").view(
        b, length, c, h + 2 * shift, w + 2 * shift
    )
    offsets = torch.randint(0, 2 * shift + 1, (b, 2), generator=generator).tolist()
    return torch.stack(
        [padded[i, :, :, dy : dy + h, dx : dx + w] for i, (dy, dx) in enumerate(offsets)]
    )


def prepare(batch: dict[str, Any], cfg: TrainPolicyConfig, device: torch.device) -> dict[str, Any]:
    """Augment (seeded by seed, epoch, environment) and move an iteration's tensors to `device`."""
    seed = int(
        np.random.default_rng([cfg.seed, batch["epoch"], batch["env_index"]]).integers(2**62)
    )
    generator = torch.Generator().manual_seed(seed)
    out = {}
    for key in ("demos", "rollouts"):
        group = {k: v.to(device) for k, v in batch[key].items() if isinstance(v, torch.Tensor)}
        if "frames" in group:  # cached features of a frozen head are not shifted
            group["frames"] = random_shift(group["frames"], cfg.shift, generator)
        out[key] = group
    return out


def freeze_encoder(policy: torch.nn.Module, path: Path) -> str:
    """Load the scene encoder's visual head into `policy.visual` and freeze it; returns the
    encoder checkpoint's sha256."""
    from aed_models.encoder import load_encoder

    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no scene encoder (this policy's visual head is the frozen scene encoder); "
            "train it first with `aed train-encoder`"
        )
    encoder = load_encoder(path)
    if encoder.config.visual != policy.config.visual:
        raise ValueError(
            f"{path}: a scene encoder with visual head {encoder.config.visual}, the policy's is "
            f"{policy.config.visual}"
        )
    policy.visual.load_state_dict(encoder.visual.state_dict())
    policy.visual.requires_grad_(False)
    return encoder.sha256


@locks_out_folder  # one training per out folder (aed_tasks.locks)
def train_policy(cfg: TrainPolicyConfig, policy_cfg: PolicyConfig | None = None) -> Path:
    """Train, checkpointing every epoch; returns the final checkpoint `<out>/policy.pt`.

    `policy_cfg` replaces the profile's policy config (tests use tiny ones).
    """
    out: Path = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    last_path, final_path, log_path = out / "last.pt", out / "policy.pt", out / "train_log.json"
    device = torch.device(cfg.device)
    seed_everything(cfg.seed)

    # data
    episodes = select_environments(load_episodes(cfg.data, split="base"), cfg.num_envs)
    check_task(episodes, cfg.task, cfg.data)

    # model, with the scene encoder as its frozen visual head when the config says so
    policy_cfg = policy_cfg or POLICIES.preset(cfg.policy, cfg.profile)
    policy = make_policy(cfg.policy, policy_cfg).to(device)
    features, encoder_sha = None, None
    if policy_cfg.frozen_encoder:
        encoder_sha = freeze_encoder(policy, cfg.encoder)
        features = frame_features(
            policy.visual, encoder_sha, episodes, cfg.encoder.parent / "features", cfg.progress
        )
    optimizer = torch.optim.RMSprop(
        [p for p in policy.parameters() if p.requires_grad],
        lr=cfg.lr,
        weight_decay=cfg.weight_decay,
    )
    train_config = {
        k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(cfg).items()
    }
    provenance = {
        "train_config": train_config,
        "data_key": data_key(episodes),
        "encoder_sha256": encoder_sha,
        **trained_on(episodes),
    }

    dataset = EnvironmentIterations(
        episodes,
        Composition(*cfg.composition),
        max_frames=cfg.max_frames or None,
        seed=cfg.seed,
        rollout_frames=cfg.rollout_frames,
        features=features,
    )
    logger.info(
        "%s on %s: %d environments, %d episodes", cfg.policy, cfg.data, len(dataset), len(episodes)
    )

    # resume, or start from the data's action statistics
    start_epoch, log = 0, []
    if cfg.resume and last_path.exists():
        ckpt = load_checkpoint(last_path, family=FAMILY, name=cfg.policy)
        check_same_training(last_path, ckpt.extra, train_config, provenance["data_key"])
        if ckpt.extra.get("encoder_sha256") != encoder_sha:
            raise ValueError(
                f"{last_path}: trained on another scene encoder than {cfg.encoder}; "
                "pass --no-resume to start over, or another --out"
            )
        if ckpt.config != policy.config.to_dict():
            raise ValueError(
                f"{last_path}: trained with another {cfg.policy} config ({ckpt.config}); "
                "pass --no-resume or another --out"
            )
        policy.load_state_dict(ckpt.state_dict)
        optimizer.load_state_dict(ckpt.extra["optimizer"])
        torch.set_rng_state(ckpt.extra["torch_rng"])
        start_epoch, log = ckpt.extra["epoch"], ckpt.extra["log"]
        logger.info("resumed from %s after epoch %d", last_path, start_epoch)
        if start_epoch >= cfg.epochs and final_path.exists():
            logger.info("%s: already trained for %d epochs", final_path, start_epoch)
            return final_path  # untouched: its sha256 is what rollouts and detectors are tied to
    else:
        policy.set_action_stats(rollout_actions(episodes))

    for epoch in range(start_epoch, cfg.epochs):
        policy.train()
        loader = DataLoader(
            dataset,
            sampler=EnvironmentSampler(len(dataset), 1, cfg.seed, start_epoch=epoch),
            batch_size=None,
            num_workers=cfg.workers,
        )
        sums: dict[str, float] = defaultdict(float)
        frames, start = 0, time.perf_counter()
        bar = tqdm(
            loader,
            desc=f"{cfg.policy} epoch {epoch + 1}/{cfg.epochs}",
            disable=not cfg.progress,
            leave=False,
        )
        for batch in bar:
            batch = prepare(batch, cfg, device)
            loss, parts = policy.loss(batch)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            for k, v in parts.items():
                sums[k] += v
            frames += int(batch["rollouts"]["mask"].sum() + batch["demos"]["mask"].sum())
            bar.set_postfix(loss=f"{parts['loss']:.3f}", pos_mse=f"{parts['pos_mse']:.3f}")
        seconds = time.perf_counter() - start
        entry = {
            "epoch": epoch + 1,
            **{k: v / len(dataset) for k, v in sums.items()},
            "seconds": round(seconds, 2),
            "frames_per_s": round(frames / seconds, 1),
        }
        log.append(entry)
        logger.info("epoch %d/%d: %s", epoch + 1, cfg.epochs, entry)
        save_checkpoint(
            last_path,
            family=FAMILY,
            name=cfg.policy,
            config=policy.config.to_dict(),
            state_dict=policy.state_dict(),
            extra={
                "epoch": epoch + 1,
                "optimizer": optimizer.state_dict(),
                "torch_rng": torch.get_rng_state(),
                "log": log,
                **provenance,
            },
        )
        log_path.write_text(json.dumps(log, indent=1))

    sha = save_checkpoint(
        final_path,
        family=FAMILY,
        name=cfg.policy,
        config=policy.config.to_dict(),
        state_dict=policy.state_dict(),
        extra={"epoch": cfg.epochs, "log": log, **provenance},
    )
    logger.info("wrote %s (sha256 %s)", final_path, sha[:12])
    return final_path

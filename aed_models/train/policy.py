"""Train a demonstration-conditioned policy by behaviour cloning (paper, appendix
"Training details").

Read top to bottom: config -> data -> model -> (resume) -> epochs -> final checkpoint
(`aed_models.train.common`: `last.pt` every epoch, resume to the same weights).

- An epoch walks every base environment once (shuffled); an iteration draws from one
  environment the recipe's demonstrations + agent successes. Actions are standardised with
  the training rollouts' statistics (see `DCPolicy`).
- DCT and SCAN model time step by step, so they see every rollout frame; their demonstrations
  are thinned (`PolicyConfig.demo_frames`) identically in training and online.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
import torch.nn.functional as F

from aed_models.checkpoint import Checkpoint, load_checkpoint
from aed_models.data import Composition, EnvironmentIterations
from aed_models.layout import RunLayout
from aed_models.policies import FAMILY, POLICIES, PolicyConfig, make_policy
from aed_models.recipe import PolicyRecipe
from aed_models.train.common import (
    TrainingFolder,
    TrainingRun,
    check_task,
    config_record,
    data_key,
    run_epoch,
    seed_everything,
    select_successes,
    task_episodes,
    trained_on,
)
from aed_models.train.frame_features import frame_features
from aed_models.train.localizer import located_points
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)


@dataclass
class TrainPolicyConfig(TrainingRun, PolicyRecipe):
    """Behaviour cloning of one policy on one task's base-split collection: the recipe's fields
    (epochs, lr, weight_decay, max_frames, composition, rollout_frames, shift) and what to train.
    Build it with `from_preset`, which fills the recipe of (policy, profile, task) and the
    paths of the runs layout.

    Args:
        policy: naive_dc, dct or scan.
        device: torch device.
        workers: DataLoader worker processes (0 = read in the main process).
        encoder: the scene encoder checkpoint a `frozen_encoder` policy starts from.
        localizer: the target localizer checkpoint a policy with a `localizer` reads, frozen.
        num_successes: use each environment's first N agent successes (0: all).
    """

    policy: str
    device: str = "cpu"
    workers: int = 0
    encoder: Path = Path("runs/PressButton/encoder/encoder.pt")
    localizer: Path = Path("runs/PressButton/localizer/localizer.pt")
    num_successes: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        POLICIES.check(self.policy)
        if self.num_successes < 0:
            raise ValueError(f"num_successes={self.num_successes}: must be >= 0")
        if self.workers < 0:
            raise ValueError(f"workers={self.workers}: must be >= 0")
        self.encoder, self.localizer = Path(self.encoder), Path(self.localizer)

    def model_preset(self) -> PolicyConfig:
        return POLICIES.preset(self.policy, self.profile)

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
            "localizer": layout.localizer(task),
        }
        return cls(**{**preset, **overrides})

    def recipe(self) -> PolicyRecipe:
        return PolicyRecipe(
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(PolicyRecipe)}
        )


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
    """Augment (seeded by seed, epoch, environment) and move an iteration's tensors to `device`:
    frames shifted, and each rollout's cached features dropped whole at `feature_dropout`."""
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
    if cfg.feature_dropout > 0:
        features = out["rollouts"]["features"]
        kept = torch.rand(features.shape[0], generator=generator) >= cfg.feature_dropout
        out["rollouts"]["features"] = features * kept.to(features).view(-1, 1, 1)
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


def load_frozen_localizer(path: Path):
    """The target localizer a policy reads (frozen), or a one-line error naming the command."""
    from aed_models.localizer import load_localizer

    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no target localizer (this policy reads where the demonstrations' stage "
            "targets are); train it first with `aed train-localizer`"
        )
    localizer = load_localizer(path)
    localizer.requires_grad_(False)
    return localizer


@locks_out_folder  # one training per out folder (aed_tasks.locks)
def train_policy(cfg: TrainPolicyConfig, policy_cfg: PolicyConfig | None = None) -> Path:
    """Train, checkpointing every epoch; returns the final checkpoint `<out>/policy.pt`.

    `policy_cfg` replaces the profile's policy config (tests use tiny ones).
    """
    cfg.out.mkdir(parents=True, exist_ok=True)
    device = torch.device(cfg.device)
    seed_everything(cfg.seed)

    # data
    episodes = select_successes(task_episodes(cfg.data, cfg.num_envs), cfg.num_successes)
    check_task(episodes, cfg.task, cfg.data)

    # model, with the scene encoder as its frozen visual head when the config says so
    policy_cfg = policy_cfg or cfg.model_preset()
    localizer, located = None, None
    if policy_cfg.localizer is not None:  # its size and stage count are the checkpoint's
        localizer = load_frozen_localizer(cfg.localizer)
        policy_cfg = dataclasses.replace(policy_cfg, localizer=localizer.config)
    policy = make_policy(cfg.policy, policy_cfg).to(device)
    if localizer is not None:
        policy.localizer.load_state_dict(localizer.state_dict())
        policy.localizer.requires_grad_(False)
        located = located_points(localizer, episodes, num_demos=cfg.composition[0])
    if cfg.feature_dropout > 0 and not policy_cfg.frozen_encoder:
        raise ValueError(
            f"feature_dropout={cfg.feature_dropout} drops cached features: it needs a policy "
            "with frozen_encoder=True (this one trains its visual head end to end)"
        )
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
    folder = TrainingFolder(
        cfg.out,
        "policy.pt",
        FAMILY,
        cfg.policy,
        policy.config.to_dict(),
        parse_config=type(policy.config).from_dict,
        provenance={
            "train_config": config_record(cfg),
            "data_key": data_key(episodes),
            "encoder_sha256": encoder_sha,
            "localizer_sha256": None if localizer is None else localizer.sha256,
            **trained_on(episodes),
        },
    )

    dataset = EnvironmentIterations(
        episodes,
        Composition(*cfg.composition),
        max_frames=cfg.max_frames or None,
        seed=cfg.seed,
        rollout_frames=cfg.rollout_frames,
        features=features,
        located=located,
        action_chunk=policy_cfg.action_chunk,
    )
    logger.info(
        "%s on %s: %d environments, %d episodes", cfg.policy, cfg.data, len(dataset), len(episodes)
    )

    # resume, or start from the data's action statistics
    def same(ckpt: Checkpoint) -> str | None:
        if ckpt.extra.get("encoder_sha256") != encoder_sha:
            return f"trained on another scene encoder than {cfg.encoder}"
        if ckpt.extra.get("localizer_sha256") != (localizer and localizer.sha256):
            return f"trained with another target localizer than {cfg.localizer}"
        return None

    resumed = folder.resume(policy, optimizer, same) if cfg.resume else None
    if resumed is None:
        policy.set_action_stats(rollout_actions(episodes))
    start_epoch, log = resumed or (0, [])
    if folder.finished(start_epoch, cfg.epochs):
        return folder.final

    def update(batch: dict) -> tuple[dict[str, float], int]:
        batch = prepare(batch, cfg, device)
        loss, parts = policy.loss(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        return parts, int(batch["rollouts"]["mask"].sum() + batch["demos"]["mask"].sum())

    for epoch in range(start_epoch, cfg.epochs):
        policy.train()
        desc = f"{cfg.policy} epoch {epoch + 1}/{cfg.epochs}"
        entry = run_epoch(dataset, update, epoch, cfg.seed, cfg.workers, desc, cfg.progress)
        log.append(entry)
        logger.info("epoch %d/%d: %s", epoch + 1, cfg.epochs, entry)
        folder.save_epoch(policy, optimizer, epoch + 1, log)

    return folder.save_final(policy, cfg.epochs, log)


def training_summary(checkpoint: Path) -> dict[str, Any]:
    """What a policy checkpoint trained on and what it cost, for the tables of `results/`:
    environments, demonstrations and agent successes per environment, epochs and updates,
    the epochs' seconds, and the action loss (share of the actions' variance) over its first
    and last 5 epochs, of the whole chunk and of the step's own action."""
    saved = load_checkpoint(checkpoint, family=FAMILY)
    extra, log = saved.extra, saved.extra["log"]
    cfg = extra["train_config"]
    episodes = select_successes(
        task_episodes(Path(cfg["data"]), cfg["num_envs"]), cfg.get("num_successes", 0)
    )
    per_env = {role: defaultdict(int) for role in ("demo", "agent_success")}
    for e in episodes:
        if e.role in per_env:
            per_env[e.role][e.env_index] += 1
    first, last = log[: min(5, len(log))], log[-min(5, len(log)) :]
    return {
        "policy": cfg["policy"],
        "seed": cfg["seed"],
        "train_envs": len(extra.get("train_envs", [])),
        "demos_per_env": max(per_env["demo"].values(), default=0),
        "successes_per_env": sorted(set(per_env["agent_success"].values())),
        "action_chunk": saved.config.get("action_chunk", 1),
        "epochs": len(log),
        "updates": len(log) * len(extra.get("train_envs", [])),
        "train_seconds": round(sum(e["seconds"] for e in log), 1),
        "pos_mse_first": float(np.mean([e["pos_mse"] for e in first])),
        "pos_mse_last": float(np.mean([e["pos_mse"] for e in last])),
        "own_pos_mse_last": float(np.mean([e.get("own_pos_mse", e["pos_mse"]) for e in last])),
        "grip_acc_last": float(np.mean([e["grip_acc"] for e in last])),
    }

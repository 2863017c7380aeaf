"""Train a demonstration-conditioned policy by behaviour cloning (paper, appendix "Training details").

Read top to bottom: config -> data -> model -> (resume) -> epochs -> final checkpoint.

- RMSprop, lr 1e-4, L2 weight decay 1e-2.
- An epoch walks every base environment once (shuffled); an iteration draws from one
  environment 5 demonstrations + 10 agent successes (`COMPOSITIONS["policy"]`).
- Actions are standardised with statistics of the training rollouts (see `DCPolicy`).
- After every epoch, `<out>/last.pt` holds model, optimizer, RNG state, epoch and the log,
  so an interrupted run resumes where it stopped and ends with the same weights;
  `<out>/train_log.json` holds the per-epoch losses. The result is `<out>/policy.pt`.

Profiles: `paper` keeps the paper's sizes (ResNet18 head, all frames, every base
environment, the paper's epochs per task). `mini` is sized for a 2-core CPU: the small CNN
head (no dropout) with proprioception and a stage-target head (`PolicyConfig.subgoal_weight`),
every environment of the collection, a random shift of +-4 px on frames, lr 3e-4 and no weight
decay, 100 epochs; an iteration draws 5 demonstrations + 2 successes (NaiveDC: + 8 successes,
8 random frames of each).

Why, as measured here:
- A from-scratch small CNN starts with nearly constant features and the loss sits at the
  actions' variance for ~70 iterations before it falls (PickPlace frames); RMSprop normalises
  the step, so an L2 term of 1e-2 outweighs those tiny early gradients, and lr 1e-3 collapsed
  the features.
- More, smaller updates: NaiveDC on Press Button (8 environments) reached 0.85 of the actions'
  variance after 240 iterations of 5 + 10 (460 s) and 0.61 after 800 iterations of 5 + 2
  (about the same time).
- Many environments: a small CNN regressing where the button is, trained on 8 Press Button
  environments, memorises them (21.8 cm off in unseen ones, worse than the mean's 12.5 cm);
  trained on 25 it is 4.5 cm off in unseen ones (`scripts/localization_probe.py`).
- Many scenes per update: NaiveDC on 27 Press Button environments reached 0.56 of the actions'
  variance after 21 epochs of 8 successes x 8 frames, against 0.69 after 25 epochs of
  2 successes x 32 frames (the same frames per iteration, four times the button positions).
- DCT and SCAN model time step by step, so they see every rollout frame: trained on
  subsampled episodes they would meet a different frame rate online. Their demonstrations are
  thinned (`PolicyConfig.demo_frames`) identically in training and online.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import random
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import h5py
import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader
from tqdm import tqdm

from aed_models.checkpoint import load_checkpoint, save_checkpoint
from aed_models.data import Composition, EnvironmentIterations, EnvironmentSampler, load_episodes
from aed_models.policies import FAMILY, POLICIES, PolicyConfig, make_policy, policy_config

logger = logging.getLogger(__name__)

# Paper, appendix table "FSI task configurations": epochs per task.
PAPER_EPOCHS = {"CloseDrawer": 160, "PressButton": 40, "PickPlace": 50, "MoveGlassCup": 50,
                "OrganizeTable": 50, "BackToBox": 50, "FactoryPacking": 80}  # fmt: skip
MINI = {"epochs": 100, "num_envs": None, "shift": 4, "lr": 3e-4, "weight_decay": 0.0, "composition": (5, 2)}
PAPER = {"lr": 1e-4, "weight_decay": 1e-2}
MINI_MAX_FRAMES = {"naive_dc": 8}  # others: every frame (see the module docstring)
MINI_ROLLOUT_FRAMES = {"naive_dc": "random"}
MINI_COMPOSITION = {"naive_dc": (5, 8)}  # others: MINI["composition"]


@dataclass
class TrainPolicyConfig:
    """Behaviour cloning of one policy on one task's base-split collection.

    Args:
        task: task name (e.g. PressButton).
        policy: naive_dc, dct or scan.
        profile: mini (CPU-sized) or paper (the paper's sizes).
        data: collection folder (default runs/<task>/data/base).
        out: output folder (default runs/<task>/policies/<policy>).
        epochs: epochs (default: mini 100; paper the paper's count for the task).
        num_envs: use the first N base environments (default: all).
        max_frames: frames per episode per iteration, evenly spread; 0 = all (default:
            mini 8 for naive_dc, else all).
        composition: demonstrations and agent successes per iteration (default: paper 5, 10
            as the paper; mini 5, 8 for naive_dc, else 5, 2).
        rollout_frames: how `max_frames` picks rollout frames: even, or a fresh random subset
            per draw (default: mini random for naive_dc, else even).
        shift: random-shift augmentation in pixels, per sequence (default: mini 4; paper 0).
        lr: RMSprop learning rate (default: paper 1e-4; mini 3e-4).
        weight_decay: L2 weight (default: paper 1e-2; mini 0: see the module docstring).
        seed: seeds the model, the draws and the augmentation.
        resume: continue from <out>/last.pt when it exists.
        progress: show a progress bar.
        device: torch device.
        workers: DataLoader worker processes (0 = read in the main process).
    """

    task: str = "PressButton"
    policy: str = "naive_dc"
    profile: Literal["mini", "paper"] = "mini"
    data: Path | None = None
    out: Path | None = None
    epochs: int | None = None
    num_envs: int | None = None
    max_frames: int | None = None
    rollout_frames: Literal["even", "random"] | None = None
    composition: tuple[int, int] | None = None
    shift: int | None = None
    lr: float | None = None
    weight_decay: float | None = None
    seed: int = 0
    resume: bool = True
    progress: bool = True
    device: str = "cpu"
    workers: int = 0

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ValueError(f"policy={self.policy!r}: known {', '.join(POLICIES)}")
        resolve_schedule(self, MINI, MINI_MAX_FRAMES.get(self.policy, 0))
        if self.composition is None and self.profile == "mini":
            self.composition = MINI_COMPOSITION.get(self.policy, MINI["composition"])
        if self.composition is not None:
            self.composition = tuple(int(n) for n in self.composition)
            if len(self.composition) != 2 or min(self.composition) < 1:
                raise ValueError(f"composition={self.composition}: (demos >= 1, successes >= 1)")
        if self.rollout_frames is None:
            self.rollout_frames = MINI_ROLLOUT_FRAMES.get(self.policy, "even") if self.profile == "mini" else "even"
        if self.shift is None:
            self.shift = MINI["shift"] if self.profile == "mini" else 0
        if self.shift < 0:
            raise ValueError(f"shift={self.shift}: must be >= 0")
        self.data = Path(self.data) if self.data is not None else Path("runs") / self.task / "data" / "base"
        self.out = Path(self.out) if self.out is not None else Path("runs") / self.task / "policies" / self.policy


def resolve_schedule(cfg: Any, mini: dict[str, Any], mini_max_frames: int) -> None:
    """Fill a training config's unset epochs, num_envs, max_frames, lr and weight_decay from its
    profile (`paper`: the paper's epochs for the task, every environment, all frames, lr 1e-4,
    L2 1e-2; `mini`: the values in `mini`), then check them. Shared by policies and detectors."""
    if cfg.profile not in ("mini", "paper"):
        raise ValueError(f"profile={cfg.profile!r}: mini or paper")
    is_mini = cfg.profile == "mini"
    if cfg.epochs is None:
        if not is_mini and cfg.task not in PAPER_EPOCHS:
            raise ValueError(f"task={cfg.task!r}: no paper epoch count (known {sorted(PAPER_EPOCHS)}); pass epochs")
        cfg.epochs = mini["epochs"] if is_mini else PAPER_EPOCHS[cfg.task]
    if cfg.num_envs is None and is_mini:
        cfg.num_envs = mini["num_envs"]
    if cfg.max_frames is None:
        cfg.max_frames = mini_max_frames if is_mini else 0
    for name in ("lr", "weight_decay"):
        if getattr(cfg, name) is None:
            setattr(cfg, name, (mini if is_mini else PAPER)[name])
    for name in ("epochs", "num_envs"):
        value = getattr(cfg, name)
        if value is not None and value < 1:
            raise ValueError(f"{name}={value}: must be >= 1")
    if cfg.max_frames < 0 or cfg.max_frames == 1:
        raise ValueError(f"max_frames={cfg.max_frames}: 0 (all) or >= 2")
    if cfg.lr <= 0 or cfg.weight_decay < 0:
        raise ValueError(f"lr={cfg.lr}, weight_decay={cfg.weight_decay}: lr > 0, weight_decay >= 0")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


def select_environments(episodes: list, num_envs: int | None) -> list:
    """The episodes of the first `num_envs` environments (by index)."""
    if num_envs is None:
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
    padded = F.pad(frames.flatten(0, 1), (shift,) * 4, mode="replicate").view(b, length, c, h + 2 * shift, w + 2 * shift)
    offsets = torch.randint(0, 2 * shift + 1, (b, 2), generator=generator).tolist()
    return torch.stack([padded[i, :, :, dy : dy + h, dx : dx + w] for i, (dy, dx) in enumerate(offsets)])


def prepare(batch: dict[str, Any], cfg: TrainPolicyConfig, device: torch.device) -> dict[str, Any]:
    """Augment (seeded by seed, epoch, environment) and move an iteration's tensors to `device`."""
    seed = int(np.random.default_rng([cfg.seed, batch["epoch"], batch["env_index"]]).integers(2**62))
    generator = torch.Generator().manual_seed(seed)
    out = {}
    for key in ("demos", "rollouts"):
        group = {k: v.to(device) for k, v in batch[key].items() if isinstance(v, torch.Tensor)}
        group["frames"] = random_shift(group["frames"], cfg.shift, generator)
        out[key] = group
    return out


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
    composition = Composition(*cfg.composition) if cfg.composition else "policy"
    dataset = EnvironmentIterations(episodes, composition, max_frames=cfg.max_frames or None, seed=cfg.seed,
                                    rollout_frames=cfg.rollout_frames)  # fmt: skip
    logger.info("%s on %s: %d environments, %d episodes", cfg.policy, cfg.data, len(dataset), len(episodes))

    # model and optimiser
    policy_cfg = policy_cfg or policy_config(cfg.policy, cfg.profile)
    policy = make_policy(cfg.policy, policy_cfg).to(device)
    optimizer = torch.optim.RMSprop(policy.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    train_config = {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(cfg).items()}
    provenance = {"train_config": train_config, **trained_on(episodes)}

    # resume, or start from the data's action statistics
    start_epoch, log = 0, []
    if cfg.resume and last_path.exists():
        ckpt = load_checkpoint(last_path, family=FAMILY, name=cfg.policy)
        if ckpt.config != policy.config.to_dict():
            raise ValueError(f"{last_path}: trained with another {cfg.policy} config ({ckpt.config}); "
                             "pass --no-resume or another --out")  # fmt: skip
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
        loader = DataLoader(dataset, sampler=EnvironmentSampler(len(dataset), 1, cfg.seed, start_epoch=epoch),
                            batch_size=None, num_workers=cfg.workers)  # fmt: skip
        sums: dict[str, float] = defaultdict(float)
        frames, start = 0, time.perf_counter()
        bar = tqdm(loader, desc=f"{cfg.policy} epoch {epoch + 1}/{cfg.epochs}", disable=not cfg.progress, leave=False)
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
        entry = {"epoch": epoch + 1, **{k: v / len(dataset) for k, v in sums.items()},
                 "seconds": round(seconds, 2), "frames_per_s": round(frames / seconds, 1)}  # fmt: skip
        log.append(entry)
        logger.info("epoch %d/%d: %s", epoch + 1, cfg.epochs, entry)
        save_checkpoint(last_path, family=FAMILY, name=cfg.policy, config=policy.config.to_dict(),
                        state_dict=policy.state_dict(),
                        extra={"epoch": epoch + 1, "optimizer": optimizer.state_dict(), "torch_rng": torch.get_rng_state(),
                               "log": log, **provenance})  # fmt: skip
        log_path.write_text(json.dumps(log, indent=1))

    sha = save_checkpoint(final_path, family=FAMILY, name=cfg.policy, config=policy.config.to_dict(),
                          state_dict=policy.state_dict(),
                          extra={"epoch": cfg.epochs, "log": log, **provenance})  # fmt: skip
    logger.info("wrote %s (sha256 %s)", final_path, sha[:12])
    return final_path

"""What every training shares: its data checks, and its folder's checkpoints and resume.

A training folder holds `last.pt` after every epoch (model, optimizer, torch RNG state, epoch,
log and provenance), `train_log.json` (the per-epoch log) and the final checkpoint. A killed
run resumes from `last.pt` to the same weights; a run with other data or settings refuses it,
naming the first difference.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import random
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from aed_models.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from aed_models.data import EnvironmentSampler, load_episodes
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, Recipe, check_profile

logger = logging.getLogger(__name__)

# What a resumed training must share with the one it continues (its epochs may grow).
RESUME_FIELDS = (
    "task",
    "policy",
    "detector",
    "profile",
    "data",
    "num_envs",
    "num_successes",
    "seed",
    "lr",
    "weight_decay",
    "max_frames",
    "composition",
    "rollout_frames",
    "shift",
    "feature_dropout",
    "augment",
    "precision",
)
# A field that checkpoints written before it existed trained without: its value then.
ABSENT_MEANS = {"feature_dropout": 0.0, "precision": "fp32"}


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
    stored = {**ABSENT_MEANS, **extra.get("train_config", {})}
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


def task_episodes(data: Path, num_envs: int) -> list:
    """The base episodes of a collection's first `num_envs` environments (0: all) that do the
    task: exploration episodes (`aed collect --num-explore`) are the scene encoder's alone."""
    episodes = [e for e in load_episodes(data, split="base") if e.role != "explore"]
    return select_environments(episodes, num_envs)


def select_environments(episodes: list, num_envs: int) -> list:
    """The episodes of the first `num_envs` environments (by index; 0: all)."""
    if not num_envs:
        return episodes
    keep = set(sorted({e.env_index for e in episodes})[:num_envs])
    return [e for e in episodes if e.env_index in keep]


def select_successes(episodes: list, num_successes: int) -> list:
    """Keep each environment's first `num_successes` agent successes in collection order (0:
    all); every other episode stays. How a training-data curve takes a prefix of one
    collection."""
    if not num_successes:
        return episodes
    order = sorted(
        (e for e in episodes if e.role == "agent_success"),
        key=lambda e: (e.env_index, e.path.name, int(e.traj.rsplit("_", 1)[1])),
    )
    seen: dict[int, int] = defaultdict(int)
    keep = set()
    for e in order:
        if seen[e.env_index] < num_successes:
            seen[e.env_index] += 1
            keep.add((e.path, e.traj))
    return [e for e in episodes if e.role != "agent_success" or (e.path, e.traj) in keep]


def trained_on(episodes: list) -> dict[str, Any]:
    """What a checkpoint records of its training data: the split and environment indices, so
    that evaluation and calibration can refuse to score a model where it trained."""
    return {"train_split": "base", "train_envs": sorted({int(e.env_index) for e in episodes})}


def run_epoch(
    dataset: Dataset,
    update: Callable[[Any], tuple[dict[str, float], int]],
    epoch: int,
    seed: int,
    workers: int = 0,
    desc: str = "",
    progress: bool = False,
) -> dict[str, float]:
    """One epoch: every environment of `dataset` once, in `epoch`'s seeded order. `update(item)`
    takes one optimiser step and returns its losses and how many frames it read. Returns the
    epoch's log entry: the mean losses, the seconds and the frames per second."""
    loader = DataLoader(
        dataset,
        sampler=EnvironmentSampler(len(dataset), 1, seed, start_epoch=epoch),
        batch_size=None,
        num_workers=workers,
    )
    sums: dict[str, float] = defaultdict(float)
    frames, start = 0, time.perf_counter()
    bar = tqdm(loader, desc=desc, disable=not progress, leave=False)
    for item in bar:
        parts, read = update(item)
        for k, v in parts.items():
            sums[k] += v
        frames += read
        bar.set_postfix(loss=f"{parts['loss']:.3f}")
    seconds = time.perf_counter() - start
    return {
        "epoch": epoch + 1,
        **{k: v / len(dataset) for k, v in sums.items()},
        "seconds": round(seconds, 2),
        "frames_per_s": round(frames / seconds, 1),
    }


def config_record(cfg: Any) -> dict[str, Any]:
    """A training config as stored in its checkpoints (paths as strings)."""
    return {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(cfg).items()}


@dataclass(kw_only=True)
class TrainingRun:
    """What every training names beside its recipe: the task, the preset, its data and folder.

    Args:
        task: task name (e.g. PressButton).
        profile: the preset of the model's sizes and of the recipe (mini, paper, demo).
        data: collection folder.
        out: output folder (checkpoints and log).
        num_envs: use the first N base environments (0: all).
        seed: seeds the model, the draws and the augmentation.
        resume: continue from <out>/last.pt when it exists.
        progress: show progress bars.
    """

    task: str
    profile: Profile
    data: Path
    out: Path
    num_envs: int = 0
    seed: int = 0
    resume: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()  # the recipe's checks
        check_profile(self.profile)
        if self.num_envs < 0:
            raise ValueError(f"num_envs={self.num_envs}: must be >= 0")
        self.data, self.out = Path(self.data), Path(self.out)

    def model_preset(self) -> Any:
        """The config of the model this run trains when it is given none: the profile's
        preset. It is part of what an `aed experiments` job is, so a changed preset retrains."""
        raise NotImplementedError


@dataclass(kw_only=True)
class TaskModelTraining(TrainingRun):
    """What to train once per task before its policies (the mini scene encoder, the target
    localizer), on the task's base collection; a subclass names its recipe (build it with
    `from_preset`)."""

    recipe: ClassVar[type[Recipe]]  # the recipe whose preset fills the other fields
    layout_name: ClassVar[str]  # the `RunLayout` method naming the final checkpoint
    not_in_paper: ClassVar[str]  # why the paper profile has no such model

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.profile == "paper":
            raise ValueError(f"profile='paper': {self.not_in_paper}")

    @classmethod
    def from_preset(
        cls,
        task: str = "PressButton",
        profile: str = "mini",
        runs: Path = Path("runs"),
        **overrides: Any,
    ) -> Self:
        layout = RunLayout(runs)
        preset = {
            **dataclasses.asdict(cls.recipe.preset(profile)),
            "task": task,
            "profile": profile,
            "data": layout.data(task, "base"),
            "out": getattr(layout, cls.layout_name)(task).parent,
        }
        return cls(**{**preset, **overrides})


@dataclass
class TrainingFolder:
    """The checkpoints of one training: `<out>/last.pt`, `<out>/<final>`, `<out>/train_log.json`.

    `model_config` and `provenance` (the training config as `train_config`, the data key, the
    environments...) go into every checkpoint; `family` and `name` type them. `parse_config`
    reads a stored model config (fields added since take their defaults): a `last.pt` whose
    config parses to another is not resumed.
    """

    out: Path
    final_name: str
    family: str
    name: str
    model_config: dict[str, Any]
    provenance: dict[str, Any]
    parse_config: Callable[[dict[str, Any]], Any]

    @property
    def last(self) -> Path:
        return self.out / "last.pt"

    @property
    def final(self) -> Path:
        return self.out / self.final_name

    def resume(
        self,
        model: nn.Module,
        optimizer: torch.optim.Optimizer,
        same: Callable[[Checkpoint], str | None] | None = None,
    ) -> tuple[int, list[dict[str, Any]]] | None:
        """Restore model, optimizer and torch RNG from `last.pt` if there is one; returns the
        epochs done and the log (None: nothing to resume). Refuses one of another training:
        other settings, data or model config, or what `same(checkpoint)` names (a message,
        None if alike)."""
        if not self.last.exists():
            return None
        ckpt = load_checkpoint(self.last, family=self.family, name=self.name)
        check_same_training(
            self.last, ckpt.extra, self.provenance["train_config"], self.provenance["data_key"]
        )
        if self.parse_config(ckpt.config) != self.parse_config(self.model_config):
            problem = f"trained with another {self.name} {self.family} config ({ckpt.config})"
        else:
            problem = same(ckpt) if same is not None else None
        if problem:
            raise ValueError(
                f"{self.last}: {problem}; pass --no-resume to start over, or another --out"
            )
        model.load_state_dict(ckpt.state_dict)
        optimizer.load_state_dict(ckpt.extra["optimizer"])
        torch.set_rng_state(ckpt.extra["torch_rng"])
        logger.info("resumed from %s after epoch %d", self.last, ckpt.extra["epoch"])
        return ckpt.extra["epoch"], ckpt.extra["log"]

    def finished(self, epochs_done: int, epochs: int) -> bool:
        """Whether the final checkpoint is there for `epochs` (it is then left untouched: its
        sha256 is what rollouts and detectors are tied to)."""
        done = epochs_done >= epochs and self.final.exists()
        if done:
            logger.info("%s: already trained for %d epochs", self.final, epochs_done)
        return done

    def save_epoch(
        self, model: nn.Module, optimizer: torch.optim.Optimizer, epoch: int, log: list
    ) -> None:
        """`last.pt` and `train_log.json` after `epoch` epochs."""
        extra = {
            **self.provenance,
            "epoch": epoch,
            "optimizer": optimizer.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "log": log,
        }
        self._save(self.last, model, extra)
        (self.out / "train_log.json").write_text(json.dumps(log, indent=1))

    def save_final(self, model: nn.Module, epochs: int, log: list) -> Path:
        sha = self._save(self.final, model, {**self.provenance, "epoch": epochs, "log": log})
        logger.info("wrote %s (sha256 %s)", self.final, sha[:12])
        return self.final

    def _save(self, path: Path, model: nn.Module, extra: dict[str, Any]) -> str:
        return save_checkpoint(
            path,
            family=self.family,
            name=self.name,
            config=self.model_config,
            state_dict=model.state_dict(),
            extra=extra,
        )

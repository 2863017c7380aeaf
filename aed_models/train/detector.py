"""Train an error detector on base-split rollouts (paper, appendix "Error Detector Details").

Read top to bottom: config -> data (frames, or cached policy features) -> model -> (resume)
-> epochs -> final checkpoint (`aed_models.train.common`: `last.pt` every epoch, resume).

- An epoch walks every base environment once (shuffled); an iteration draws from one
  environment the recipe's demonstrations + agent successes + agent failures (successes only
  for SVDDED and RND-OE), the rollouts augmented (keep / drop / swap / copy) unless told not.
- Policy-dependent detectors (PrObe, RND-OE) never see images: they read the frozen policy's
  features, computed once per policy checkpoint (`aed_models.train.feature_cache`).
- `<out>/detector.pt` records the task, the profile and, for policy-dependent detectors, the
  policy's name and checkpoint sha256.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from aed_models.augment import RolloutAugment
from aed_models.checkpoint import Checkpoint, file_sha256
from aed_models.data import Composition, EnvironmentIterations
from aed_models.detectors import DETECTORS, FAMILY, make_detector, requires_policy
from aed_models.detectors.base import to_device
from aed_models.layout import RunLayout
from aed_models.recipe import DetectorRecipe
from aed_models.train.common import (
    TrainingFolder,
    TrainingRun,
    check_task,
    config_record,
    data_key,
    run_epoch,
    seed_everything,
    task_episodes,
    trained_on,
)
from aed_models.train.feature_cache import FeatureCache, FeatureIterations
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)


@dataclass
class TrainDetectorConfig(TrainingRun, DetectorRecipe):
    """Training of one error detector on one task's base-split collection: the recipe's fields
    (epochs, lr, weight_decay, max_frames, composition, precision) and what to train. Build it with
    `from_preset`, which fills the recipe of (detector, profile, task) and the layout's paths.

    Args:
        detector: svdd_ed, taskemb_ed, lstm_ed, dct_ed, probe or rnd_oe.
        policy: the frozen policy's checkpoint (probe, rnd_oe only; None for the others).
        augment: rollout augmentation (paper: on; off for the ablation).
        device: torch device of the detector (and of the policy while features are cached).
        workers: DataLoader worker processes (0 = read in the main process).
    """

    detector: str
    policy: str | None = None
    augment: bool = True
    device: str = "cpu"
    workers: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        DETECTORS.check(self.detector)
        if requires_policy(self.detector) and not self.policy:
            raise ValueError(
                f"policy=None: detector {self.detector!r} reads a policy's features; "
                "name the policy"
            )
        if self.workers < 0:
            raise ValueError(f"workers={self.workers}: must be >= 0")

    def model_preset(self) -> Any:
        return DETECTORS.preset(self.detector, self.profile)

    @classmethod
    def from_preset(
        cls,
        task: str = "PressButton",
        detector: str = "probe",
        profile: str = "mini",
        policy: str | None = None,
        runs: Path = Path("runs"),
        **overrides: Any,
    ) -> TrainDetectorConfig:
        """The recipe of (detector, profile, task), the layout's paths under `runs`, then
        `overrides`. `policy` is a policy name (its checkpoint in the layout) or a checkpoint
        path."""
        layout = RunLayout(runs)
        label = None
        if policy is not None and requires_policy(detector):
            path = Path(policy)
            label = path.parent.name if path.suffix else path.name
            policy = str(path if path.suffix or path.is_dir() else layout.policy(task, policy))
        preset = {
            **dataclasses.asdict(DETECTORS.recipe(detector, profile, task)),
            "task": task,
            "detector": detector,
            "profile": profile,
            "policy": policy,
            "data": layout.data(task, "base"),
            "out": layout.detector(task, detector, label or "").parent,
        }
        return cls(**{**preset, **overrides})

    def recipe(self) -> DetectorRecipe:
        return DetectorRecipe(
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(DetectorRecipe)}
        )

    def policy_path(self) -> Path:
        """The policy checkpoint: `policy` itself, or `policy.pt` in it when it is a folder."""
        assert self.policy is not None
        path = Path(self.policy)
        return path / "policy.pt" if path.is_dir() else path


def load_frozen_policy(cfg: TrainDetectorConfig) -> tuple[Any, str, str]:
    """(policy in eval mode with gradients off, its registry name, its checkpoint sha256)."""
    from aed_models.policies import load_policy

    path = cfg.policy_path()
    if not path.is_file():
        raise FileNotFoundError(
            f"policy={cfg.policy!r}: no checkpoint at {path} (train the policy first)"
        )
    policy = load_policy(path)  # checks the family: a detector file here is refused
    sha = file_sha256(path)
    policy.requires_grad_(False)
    return policy, policy.name, sha


def build_dataset(
    cfg: TrainDetectorConfig, detector_name: str, episodes: list, policy: Any, policy_sha: str
) -> Any:
    """Frame iterations for the visual baselines, cached-feature iterations for the others."""
    model_type = DETECTORS.model_type(detector_name)
    demos, successes, failures = cfg.composition
    only_successes = model_type.trains_on == "successes"
    composition = (
        Composition(demos, successes + failures, 0)
        if only_successes
        else Composition(demos, successes, failures)
    )
    augment = RolloutAugment(enabled=cfg.augment)
    max_frames = cfg.max_frames or None
    if not model_type.requires_policy:
        return EnvironmentIterations(
            episodes, composition, augment=augment, max_frames=max_frames, seed=cfg.seed
        )
    cache = FeatureCache(_features_root(cfg), policy_sha)
    written = cache.build(episodes, policy, seed=cfg.seed, progress=cfg.progress)
    logger.info("policy features: %s (%d shards computed)", cache.dir, written)
    return FeatureIterations(
        episodes, cache, composition, augment=augment, max_frames=max_frames, seed=cfg.seed
    )


def _features_root(cfg: TrainDetectorConfig) -> Path:
    """runs/<task>/features beside the collection's runs/<task>/data/base when it lies there."""
    data = Path(cfg.data)
    if data.parent.name == "data":
        return data.parent.parent / "features"
    return Path(cfg.out) / "features"


def autocast(precision: str, device: torch.device) -> torch.autocast:
    """The forward pass's autocast: bfloat16 under `bf16`, off under `fp32`."""
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16")


def prepare(
    batch: dict[str, Any], model_type: type, device: torch.device
) -> tuple[dict[str, Any], Any]:
    """The detector's (batch, policy_features) from a dataset item, on `device`."""
    if model_type.requires_policy:
        return to_device({"rollouts": batch["rollouts"]}, device), to_device(
            batch["features"], device
        )
    return to_device({"demos": batch["demos"], "rollouts": batch["rollouts"]}, device), None


@locks_out_folder  # one training per out folder (aed_tasks.locks)
def train_detector(cfg: TrainDetectorConfig, detector_cfg: Any = None) -> Path:
    """Train, checkpointing every epoch; returns the final checkpoint `<out>/detector.pt`.

    `detector_cfg` replaces the profile's detector config (tests use tiny ones); a
    policy-dependent detector's feature sizes are always taken from the policy.
    """
    cfg.out.mkdir(parents=True, exist_ok=True)
    seed_everything(cfg.seed)
    device = torch.device(cfg.device)
    model_type = DETECTORS.model_type(cfg.detector)

    # the frozen policy (policy-dependent detectors only)
    policy, policy_name, policy_sha = None, None, None
    if model_type.requires_policy:
        policy, policy_name, policy_sha = load_frozen_policy(cfg)
        policy.to(device)

    # data
    episodes = task_episodes(cfg.data, cfg.num_envs)
    check_task(episodes, cfg.task, cfg.data)
    dataset = build_dataset(cfg, cfg.detector, episodes, policy, policy_sha or "")
    logger.info(
        "%s on %s: %d environments, %d episodes",
        cfg.detector,
        cfg.data,
        len(dataset),
        len(episodes),
    )

    # model and optimiser
    detector_cfg = detector_cfg or cfg.model_preset()
    overrides = {"history_dim": policy.history_dim} if policy is not None else {}
    if policy is not None and cfg.detector == "probe":
        overrides["task_dim"] = policy.task_dim
    detector = make_detector(cfg.detector, detector_cfg, **overrides).to(device)
    del policy  # features are cached: the policy is not needed any more
    optimizer = torch.optim.RMSprop(
        [p for p in detector.parameters() if p.requires_grad],
        lr=cfg.lr,
        weight_decay=cfg.weight_decay,
    )
    folder = TrainingFolder(
        cfg.out,
        "detector.pt",
        FAMILY,
        cfg.detector,
        detector.config.to_dict(),
        parse_config=lambda stored: DETECTORS.config_from_dict(cfg.detector, stored),
        provenance={
            "task": cfg.task,
            "profile": cfg.profile,
            "policy_name": policy_name,
            "policy_sha256": policy_sha,
            "train_config": config_record(cfg),
            "data_key": data_key(episodes),
            **trained_on(episodes),
        },
    )

    def same(ckpt: Checkpoint) -> str | None:
        if ckpt.extra.get("policy_sha256") != policy_sha:
            return f"trained on policy {ckpt.extra.get('policy_sha256')}, not {policy_sha}"
        return None

    resumed = folder.resume(detector, optimizer, same) if cfg.resume else None
    start_epoch, log = resumed or (0, [])
    if folder.finished(start_epoch, cfg.epochs):
        return folder.final

    def update(item: Any) -> tuple[dict[str, float], int]:
        batch, features = prepare(item, model_type, device)
        with autocast(cfg.precision, device):
            loss, parts = detector.loss(batch, features)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        return {"loss": float(loss.detach()), **parts}, int(batch["rollouts"]["mask"].sum())

    for epoch in range(start_epoch, cfg.epochs):
        detector.train()
        desc = f"{cfg.detector} epoch {epoch + 1}/{cfg.epochs}"
        entry = run_epoch(dataset, update, epoch, cfg.seed, cfg.workers, desc, cfg.progress)
        log.append(entry)
        logger.info("epoch %d/%d: %s", epoch + 1, cfg.epochs, entry)
        folder.save_epoch(detector, optimizer, epoch + 1, log)

    return folder.save_final(detector, cfg.epochs, log)

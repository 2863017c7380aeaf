"""Train the scene encoder: regress where things are (`aed_models.data.scene_state`) from frames.

Read top to bottom: config -> data -> model -> (resume) -> epochs -> final checkpoint.

Every stored frame carries the full env state, so every frame of every episode (demonstrations,
successes, failures) is a labelled example of where the TCP, the stage target and the task
objects are. An epoch takes `max_frames` random frames of every training episode, shuffled
into updates of `batch_episodes` episodes, each sequence randomly shifted; Adam minimises the
MSE of the standardised state. `<out>/last.pt` after every epoch (resume), `<out>/encoder.pt`
at the end, `<out>/train_log.json` the per-epoch losses.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import h5py
import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from aed_models.data import EpisodeReader, load_episodes, scene_state, scene_state_names
from aed_models.encoder import FAMILY, NAME, EncoderConfig, EncoderRecipe
from aed_models.encoder.modeling_encoder import SceneEncoder
from aed_models.recipe import Recipe
from aed_models.train.common import (
    TaskModelTraining,
    TrainingFolder,
    check_task,
    config_record,
    data_key,
    seed_everything,
    select_environments,
    trained_on,
)
from aed_models.train.policy import random_shift
from aed_tasks import trajectory
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)


@dataclass
class TrainEncoderConfig(TaskModelTraining, EncoderRecipe):
    """The scene encoder of one task, on its base collection: the recipe's fields and what to
    train (build it with `from_preset`)."""

    recipe: ClassVar[type[Recipe]] = EncoderRecipe
    layout_name: ClassVar[str] = "encoder"
    not_in_paper: ClassVar[str] = "the paper trains its visual heads end to end"

    def model_preset(self) -> EncoderConfig:
        return EncoderConfig.preset(self.profile)


class SceneFrames:
    """Frames of episodes with their scene state (`scene_state`, read once per episode)."""

    def __init__(self, episodes: Sequence[trajectory.EpisodeRef], camera: str = "front"):
        self.episodes = list(episodes)
        self.reader = EpisodeReader(camera)
        self.states = [read_scene_state(ref) for ref in self.episodes]
        for ref, state in zip(self.episodes, self.states, strict=True):
            if state.shape[1] != self.states[0].shape[1]:
                first = self.episodes[0]
                raise ValueError(
                    f"{ref.path} {ref.traj}: a scene state of {state.shape[1]} columns, "
                    f"{self.states[0].shape[1]} in {first.path} {first.traj}: the episodes of "
                    "one encoder must hold the same task objects"
                )

    def draw(self, i: int, indices: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """(frames (n, 4, H, W), states (n, D)) of episode `i` at frame `indices`."""
        seq = self.reader.read(self.episodes[i], indices)
        return seq.frames, torch.from_numpy(self.states[i][indices])


def read_scene_state(ref: trajectory.EpisodeRef) -> np.ndarray:
    """The episode's scene state; an exploration episode has no stage target (NaN)."""
    with h5py.File(ref.path, "r") as h5:
        return scene_state(h5[ref.traj], stage_target=ref.role != "explore")


def state_loss(
    predicted: torch.Tensor, states: torch.Tensor, encoder: SceneEncoder
) -> torch.Tensor:
    """MSE of the standardised state over the known (finite) entries."""
    known = torch.isfinite(states)
    target = (states - encoder.state_mean) / encoder.state_std
    return F.mse_loss(predicted[known], target[known])


def state_names(ref: trajectory.EpisodeRef) -> tuple[str, ...]:
    with h5py.File(ref.path, "r") as h5:
        return tuple(scene_state_names(h5[ref.traj]))


def epoch_updates(
    num_episodes: int, lengths: Sequence[int], recipe: EncoderRecipe, seed: int, epoch: int
) -> list[list[tuple[int, np.ndarray]]]:
    """The epoch's updates: groups of `batch_episodes` episodes, each with its random frames."""
    rng = np.random.default_rng([seed, epoch])
    order = rng.permutation(num_episodes)
    picks = [
        (int(i), np.sort(rng.choice(lengths[i], min(recipe.max_frames, lengths[i]), replace=False)))
        for i in order
    ]
    step = recipe.batch_episodes
    return [picks[k : k + step] for k in range(0, len(picks), step)]


def update_batch(
    data: SceneFrames,
    update: list[tuple[int, np.ndarray]],
    recipe: EncoderRecipe,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One update's frames (augmented per episode) and scene states."""
    frames, states = [], []
    for i, indices in update:
        f, s = data.draw(i, indices)
        frames.append(random_shift(f[None], recipe.shift, generator)[0])
        states.append(s)
    return torch.cat(frames), torch.cat(states)


@locks_out_folder  # one training per out folder (aed_tasks.locks)
def train_encoder(cfg: TrainEncoderConfig, encoder_cfg: EncoderConfig | None = None) -> Path:
    """Train, checkpointing every epoch; returns the final checkpoint `<out>/encoder.pt`.

    `encoder_cfg` replaces the profile's encoder config (tests use tiny ones)."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    seed_everything(cfg.seed)

    # data
    episodes = select_environments(load_episodes(cfg.data, split="base"), cfg.num_envs)
    check_task(episodes, cfg.task, cfg.data)
    data = SceneFrames(episodes)
    lengths = [ref.num_frames for ref in episodes]
    logger.info(
        "scene encoder on %s: %d episodes, %d frames", cfg.data, len(episodes), sum(lengths)
    )

    # model and optimiser
    config = dataclasses.replace(
        encoder_cfg or cfg.model_preset(), state_names=state_names(episodes[0])
    )
    encoder = SceneEncoder(config)
    optimizer = torch.optim.Adam(encoder.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    folder = TrainingFolder(
        cfg.out,
        "encoder.pt",
        FAMILY,
        NAME,
        config.to_dict(),
        parse_config=EncoderConfig.from_dict,
        provenance={
            "train_config": config_record(cfg),
            "data_key": data_key(episodes),
            **trained_on(episodes),
        },
    )

    resumed = folder.resume(encoder, optimizer) if cfg.resume else None
    if resumed is None:
        encoder.set_state_stats(torch.from_numpy(np.concatenate(data.states)))
    start_epoch, log = resumed or (0, [])
    if folder.finished(start_epoch, cfg.epochs):
        return folder.final

    for epoch in range(start_epoch, cfg.epochs):
        encoder.train()
        generator = torch.Generator().manual_seed(
            int(np.random.default_rng([cfg.seed, epoch, 1]).integers(2**62))
        )
        updates = epoch_updates(len(episodes), lengths, cfg, cfg.seed, epoch)
        total, start = 0.0, time.perf_counter()
        bar = tqdm(
            updates,
            desc=f"encoder epoch {epoch + 1}/{cfg.epochs}",
            disable=not cfg.progress,
            leave=False,
        )
        for update in bar:
            frames, states = update_batch(data, update, cfg, generator)
            _, predicted = encoder(frames)
            loss = state_loss(predicted, states, encoder)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            total += loss.item()
            bar.set_postfix(loss=f"{loss.item():.3f}")
        entry = {
            "epoch": epoch + 1,
            "state_mse": total / len(updates),
            "seconds": round(time.perf_counter() - start, 2),
        }
        log.append(entry)
        logger.info("epoch %d/%d: %s", epoch + 1, cfg.epochs, entry)
        folder.save_epoch(encoder, optimizer, epoch + 1, log)

    return folder.save_final(encoder, cfg.epochs, log)


@torch.no_grad()
def localization_errors(
    encoder: SceneEncoder,
    episodes: Sequence[trajectory.EpisodeRef],
    every: int = 4,
    mean_guess: bool = False,
) -> dict[str, float]:
    """Mean error of each predicted position (cm, per entity: `tcp`, `subgoal`, objects) and
    joint (its units x 100) over every `every`-th frame of `episodes` where it is known.
    `mean_guess` scores the training mean instead (what a head that learned nothing predicts)."""
    data = SceneFrames(episodes)
    names = encoder.config.state_names
    entities = dict.fromkeys(n.split(".")[0] for n in names)
    groups = {
        e: [k for k, n in enumerate(names) if n in (f"{e}.x", f"{e}.y", f"{e}.z")] for e in entities
    }
    groups.update({n: [k] for k, n in enumerate(names) if ".q" in n})
    errors: dict[str, list[np.ndarray]] = {name: [] for name in groups}
    for i, ref in enumerate(episodes):
        frames, states = data.draw(i, np.arange(0, ref.num_frames, every))
        predicted = (
            encoder.state_mean.expand_as(states) if mean_guess else encoder.predict_state(frames)
        )
        diff = (predicted - states).numpy()
        for name, cols in groups.items():
            errors[name].append(np.linalg.norm(diff[:, cols], axis=1))
    errors = {name: np.concatenate(e) for name, e in errors.items()}
    # unknown entries (an exploration episode's stage target) are left out
    return {n: float(np.nanmean(e) * 100) for n, e in errors.items() if np.isfinite(e).any()}

"""Train the target localizer: match where a stage ends across episodes of one environment.

Read top to bottom: config -> data -> model -> (resume) -> epochs -> final checkpoint.

Every expert episode (demonstrations and agent successes) shows where its stages ended: its
TCP on the frame after each stage completes (`aed_models.data.stage_subgoals`). A pair is two
episodes of one base environment and one stage: the query is the matching map's feature under
the first episode's stage point in its first frame; the target is the cell holding the second
episode's stage point in one of its frames before its first stage ends (the objects placed as
they were at the start). A softmax over the target frame's cells is trained (cross-entropy)
to peak there, both frames recoloured alike, so the map learns to match appearance rather
than the training split's colours. No label the deployed policy lacks: in a novel environment
the queries come from its demonstrations.
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

from aed_models.data import EpisodeReader, load_episodes, stage_end_points, stage_subgoals
from aed_models.localizer import FAMILY, NAME, LocalizerConfig, LocalizerRecipe
from aed_models.localizer.modeling_localizer import (
    StageQueries,
    TargetLocalizer,
    colour_jitter,
    sample,
    target_cells,
)
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
from aed_tasks import trajectory
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)

EXPERT_ROLES = ("demo", "agent_success")


@dataclass
class TrainLocalizerConfig(TaskModelTraining, LocalizerRecipe):
    """The target localizer of one task, on its base collection: the recipe's fields and what to
    train (build it with `from_preset`)."""

    recipe: ClassVar[type[Recipe]] = LocalizerRecipe
    layout_name: ClassVar[str] = "localizer"
    not_in_paper: ClassVar[str] = "the paper's policies have no localizer"

    def model_preset(self) -> LocalizerConfig:
        return LocalizerConfig.preset(self.profile)


@dataclass
class StageEpisode:
    """One expert episode as the localizer sees it."""

    ref: trajectory.EpisodeRef
    points: np.ndarray  # (K, 3) where its stages ended (world)
    first_stage_frames: int  # frames before its first stage ends
    intrinsic: np.ndarray  # (3, 3)
    extrinsic: np.ndarray  # (3, 4)


def stage_episode(ref: trajectory.EpisodeRef, num_stages: int, camera: str) -> StageEpisode:
    with h5py.File(ref.path, "r") as h5:
        group = h5[ref.traj]
        tcp = group["obs/extra/tcp_pose"][()][:, :3].astype(np.float32)
        stage = group["stage"][()]
        subgoal = stage_subgoals(tcp, stage)
        params = group.get(f"obs/sensor_param/{camera}")
        if params is None:
            raise ValueError(f"{ref.path.name}/{ref.traj}: no sensor_param/{camera} recorded")
        intrinsic, extrinsic = params["intrinsic_cv"][0], params["extrinsic_cv"][0]
    completed = int(stage.max()) if len(stage) else 0
    if completed < num_stages:
        raise ValueError(
            f"{ref.path.name}/{ref.traj} ({ref.role}): completes {completed} stages, "
            f"{num_stages} needed (is it a successful one?)"
        )
    try:
        points = stage_end_points(torch.from_numpy(subgoal), num_stages).numpy()
    except ValueError as e:
        raise ValueError(f"{ref.path.name}/{ref.traj} ({ref.role}): {e}") from None
    first = int(np.argmax((subgoal != subgoal[0]).any(1))) or len(subgoal)
    return StageEpisode(ref, points, first, intrinsic, extrinsic)


def task_stages(episodes: Sequence[trajectory.EpisodeRef]) -> int:
    """How many stages the task has: the most any agent success completed."""
    most = 0
    for ref in episodes:
        if ref.role == "agent_success":
            with h5py.File(ref.path, "r") as h5:
                most = max(most, int(h5[ref.traj]["stage"][()].max()))
    if most < 1:
        raise ValueError("no agent success completes a stage: nothing to locate")
    return most


def fixed_camera(infos: Sequence[StageEpisode]) -> tuple[np.ndarray, np.ndarray]:
    """The one camera every episode was seen through (the localizer lifts pixels with it)."""
    first = infos[0]
    for info in infos[1:]:
        if not (
            np.allclose(info.intrinsic, first.intrinsic, atol=1e-4)
            and np.allclose(info.extrinsic, first.extrinsic, atol=1e-5)
        ):
            raise ValueError(
                f"{info.ref.path.name}/{info.ref.traj}: another camera pose than "
                f"{first.ref.path.name}/{first.ref.traj}; the localizer needs a fixed camera"
            )
    return first.intrinsic, first.extrinsic


class StagePairs:
    """Per environment, each expert episode's frames (its first, then random ones before its
    first stage ends) and the pixels of its stage points; `batch` draws (query, target) pairs."""

    def __init__(
        self,
        infos: Sequence[StageEpisode],
        localizer: TargetLocalizer,
        max_frames: int,
        seed: int,
        camera: str = "front",
    ):
        rng = np.random.default_rng([seed, 2])
        reader = EpisodeReader(camera)
        self.episodes: dict[int, list[tuple[torch.Tensor, torch.Tensor]]] = {}
        for info in infos:
            n = max(1, min(max_frames, info.first_stage_frames))
            later = np.arange(1, info.first_stage_frames)
            picks = rng.choice(later, min(n - 1, len(later)), replace=False)
            indices = np.concatenate([[0], np.sort(picks)]).astype(np.int64)
            frames = reader.read(info.ref, indices).frames.half()
            pixels = localizer.project(torch.from_numpy(info.points))
            self.episodes.setdefault(info.ref.env_index, []).append((frames, pixels))
        reader.close()
        self.envs = sorted(e for e, eps in self.episodes.items() if len(eps) >= 2)
        if not self.envs:
            raise ValueError("no environment has two expert episodes to pair")
        self.num_stages = localizer.config.num_targets

    def batch(
        self, size: int, rng: np.random.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Pairs (size, 2, 4, H, W) (query frame, target frame), query pixels (size, 2) and
        target pixels (size, 2)."""
        frames, q_pix, t_pix = [], [], []
        for env in rng.choice(self.envs, size):
            pool = self.episodes[env]
            a, b = rng.choice(len(pool), 2, replace=False)
            k = rng.integers(self.num_stages)
            (q_frames, q_points), (t_frames, t_points) = pool[a], pool[b]
            frames.append(torch.stack([q_frames[0], t_frames[rng.integers(len(t_frames))]]))
            q_pix.append(q_points[k])
            t_pix.append(t_points[k])
        return torch.stack(frames).float(), torch.stack(q_pix), torch.stack(t_pix)


def pair_loss(
    localizer: TargetLocalizer, pairs: torch.Tensor, q_pix: torch.Tensor, t_pix: torch.Tensor
) -> torch.Tensor:
    """Cross-entropy of the target frame's cells scored by the query's feature."""
    maps = localizer.map(pairs.flatten(0, 1)).unflatten(0, (len(pairs), 2))
    stride = localizer.config.stride
    queries = sample(maps[:, 0], q_pix, stride)
    logits = localizer.map.logits(maps[:, 1], queries)
    return F.cross_entropy(logits, target_cells(t_pix, *maps.shape[-2:], stride))


@locks_out_folder  # one training per out folder (aed_tasks.locks)
def train_localizer(
    cfg: TrainLocalizerConfig, localizer_cfg: LocalizerConfig | None = None
) -> Path:
    """Train, checkpointing every epoch; returns the final checkpoint `<out>/localizer.pt`.

    `localizer_cfg` replaces the profile's config (tests use tiny ones)."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    seed_everything(cfg.seed)

    # data: the expert episodes of the training environments
    episodes = select_environments(load_episodes(cfg.data, split="base"), cfg.num_envs)
    check_task(episodes, cfg.task, cfg.data)
    experts = [e for e in episodes if e.role in EXPERT_ROLES and not e.suboptimal]
    num_stages = task_stages(experts)
    infos = [stage_episode(ref, num_stages, "front") for ref in experts]

    # model and optimiser
    config = dataclasses.replace(localizer_cfg or cfg.model_preset(), num_targets=num_stages)
    localizer = TargetLocalizer(config)
    localizer.set_camera(*(torch.from_numpy(m) for m in fixed_camera(infos)))
    start = time.perf_counter()
    data = StagePairs(infos, localizer, cfg.max_frames, cfg.seed)
    logger.info(
        "localizer on %s: %d environments, %d expert episodes, %d stages, read in %.0f s",
        cfg.data,
        len(data.envs),
        len(infos),
        num_stages,
        time.perf_counter() - start,
    )
    optimizer = torch.optim.Adam(localizer.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    folder = TrainingFolder(
        cfg.out,
        "localizer.pt",
        FAMILY,
        NAME,
        config.to_dict(),
        parse_config=LocalizerConfig.from_dict,
        provenance={
            "train_config": config_record(cfg),
            "data_key": data_key(experts),
            **trained_on(experts),
        },
    )

    resumed = folder.resume(localizer, optimizer) if cfg.resume else None
    start_epoch, log = resumed or (0, [])
    if folder.finished(start_epoch, cfg.epochs):
        return folder.final

    for epoch in range(start_epoch, cfg.epochs):
        localizer.train()
        rng = np.random.default_rng([cfg.seed, epoch])
        generator = torch.Generator().manual_seed(
            int(np.random.default_rng([cfg.seed, epoch, 1]).integers(2**62))
        )
        total, start = 0.0, time.perf_counter()
        bar = tqdm(
            range(cfg.updates),
            desc=f"localizer epoch {epoch + 1}/{cfg.epochs}",
            disable=not cfg.progress,
            leave=False,
        )
        for _ in bar:
            pairs, q_pix, t_pix = data.batch(cfg.batch, rng)
            loss = pair_loss(localizer, colour_jitter(pairs, cfg.colour, generator), q_pix, t_pix)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            total += loss.item()
            bar.set_postfix(loss=f"{loss.item():.3f}")
        entry = {
            "epoch": epoch + 1,
            "match_loss": total / cfg.updates,
            "seconds": round(time.perf_counter() - start, 2),
        }
        log.append(entry)
        logger.info("epoch %d/%d: %s", epoch + 1, cfg.epochs, entry)
        folder.save_epoch(localizer, optimizer, epoch + 1, log)

    return folder.save_final(localizer, cfg.epochs, log)


def environment_queries(
    localizer: TargetLocalizer,
    demos: Sequence[StageEpisode],
    reader: EpisodeReader,
) -> StageQueries:
    """The K stage queries of one environment from its demonstrations."""
    firsts = torch.stack([reader.read(d.ref, np.array([0])).frames[0] for d in demos])
    points = torch.from_numpy(np.stack([d.points for d in demos])).float()
    return localizer.queries(firsts, points)


@torch.no_grad()
def located_points(
    localizer: TargetLocalizer,
    episodes: Sequence[trajectory.EpisodeRef],
    num_demos: int,
    camera: str = "front",
) -> dict[tuple[str, str], np.ndarray]:
    """Where the localizer places each stage target (K, 3) in the first frame of every agent
    episode of `episodes`, queried with the first `num_demos` optimal demonstrations of its
    environment, as the policy will be at deployment; keyed by `(str(path), traj)`."""
    localizer.eval()
    k = localizer.config.num_targets
    reader = EpisodeReader(camera)
    out: dict[tuple[str, str], np.ndarray] = {}
    for env in sorted({e.env_index for e in episodes}):
        in_env = [e for e in episodes if e.env_index == env]
        demos = [e for e in in_env if e.role == "demo" and not e.suboptimal][:num_demos]
        agents = [e for e in in_env if e.role in ("agent_success", "agent_failure")]
        if not agents:
            continue
        if not demos:
            raise ValueError(f"environment {env} has no optimal demonstration to query with")
        queries = environment_queries(
            localizer, [stage_episode(d, k, camera) for d in demos], reader
        )
        firsts = torch.stack([reader.read(ref, np.array([0])).frames[0] for ref in agents])
        points = localizer.locate(firsts, queries).numpy()
        out.update({(str(ref.path), ref.traj): p for ref, p in zip(agents, points, strict=True)})
    reader.close()
    return out

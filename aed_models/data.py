"""PyTorch datasets and samplers over collected episodes (see `aed_tasks.trajectory`).

Training follows the paper: an epoch walks through every base environment once, in a
shuffled order; one iteration takes one environment and samples from it N demonstrations
plus rollouts (`COMPOSITIONS`: policy 5 demos + 10 successes; detectors 5 + 10 successes +
10 failures; SVDDED 5 + 20 successes). An environment with fewer episodes than asked is
sampled with replacement.

Frames are float32 tensors (4, 120, 160) = (C, H, W):

- channels 0-2: RGB / 255, in [0, 1];
- channel 3: depth in metres / 5 (the cameras' far plane, 5 m), in [0, 1]; 0 where the
  camera saw nothing. Stored depth is int16 millimetres, so this is `mm / 5000`.

Sequences have different lengths; a group of them is padded to the longest, with
`lengths` and a boolean `mask` (B, L). Per frame: `labels` (0 normal, 1 from the error on;
padding 0), `actions` (the action taken at that frame; the last frame of an episode,
after which none was taken, and padding get zeros) and `proprio` (`PROPRIO_DIM`: the TCP
position in metres and the two finger joints, what `proprio_from_obs` reads online) and
`subgoal` (the TCP position at which the frame's stage ends, see `stage_subgoals`: a target for
the policies' optional auxiliary loss).

Reads are lazy: only the sampled episodes, and only the frames kept, are read; each
process (DataLoader worker) opens its own HDF5 handles.
"""

from __future__ import annotations

import logging
import os
import re
from collections import defaultdict
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from aed_models.augment import RolloutAugment
from aed_models.recipe import COMPOSITIONS, Composition
from aed_tasks import trajectory
from aed_tasks.episode import frame_labels

logger = logging.getLogger(__name__)

DEPTH_SCALE_MM = 5000.0  # the cameras' far plane: depth / 5 m lies in [0, 1]
PROPRIO_DIM = 5  # TCP position (3) + finger joints (2)


def proprio_from_obs(tcp_pose: Any, qpos: Any) -> np.ndarray:
    """(..., 7) TCP pose and (..., 9) Panda qpos -> (..., 5) float32: TCP xyz, finger joints."""
    tcp_pose, qpos = (
        np.asarray(x.cpu() if isinstance(x, torch.Tensor) else x, dtype=np.float32)
        for x in (tcp_pose, qpos)
    )
    if tcp_pose.shape[-1] != 7 or qpos.shape[-1] < 2:
        raise ValueError(
            f"proprio: tcp_pose {tcp_pose.shape} and qpos {qpos.shape}: "
            "expected (..., 7) and (..., >= 2)"
        )
    return np.concatenate([tcp_pose[..., :3], qpos[..., -2:]], axis=-1)


def to_frames(rgb: np.ndarray, depth: np.ndarray, out: torch.Tensor | None = None) -> torch.Tensor:
    """(L, H, W, 3) uint8 RGB + (L, H, W, 1) int16 mm depth -> (L, 4, H, W) float32
    (see module doc).

    Writes into `out` when given (one pass over memory: a batch of 25 x 100 frames is 1.9 GB).
    """
    if out is None:
        out = torch.empty((len(rgb), 4, *rgb.shape[1:3]), dtype=torch.float32)
    out[:, :3].copy_(torch.from_numpy(np.ascontiguousarray(rgb)).permute(0, 3, 1, 2)).mul_(
        1.0 / 255.0
    )
    out[:, 3:].copy_(torch.from_numpy(np.ascontiguousarray(depth)).permute(0, 3, 1, 2))
    out[:, 3:].mul_(1.0 / DEPTH_SCALE_MM).clamp_(0.0, 1.0)
    return out


def subsample(indices: np.ndarray, max_frames: int | None) -> np.ndarray:
    """At most `max_frames` of `indices`, evenly spread, first and last kept."""
    if max_frames is None or len(indices) <= max_frames:
        return indices
    keep = np.round(np.linspace(0, len(indices) - 1, max_frames)).astype(np.int64)
    return indices[keep]


def stage_subgoals(tcp: np.ndarray, stage: np.ndarray) -> np.ndarray:
    """(T + 1, 3) TCP positions and (T,) per-step stages -> (T + 1, 3): for every frame, the TCP
    position on the frame where its stage ends (the frame after the step that completes it; the
    last frame for the final stage). Frame t + 1 follows step t, so it carries stage[t]; frame 0
    carries stage[0]."""
    frame_stage = (
        np.concatenate([stage[:1], stage]) if len(stage) else np.zeros(len(tcp), dtype=np.int64)
    )
    goals = np.empty_like(tcp)
    goals[-1] = tcp[-1]
    for i in range(len(tcp) - 2, -1, -1):
        goals[i] = goals[i + 1] if frame_stage[i] == frame_stage[i + 1] else tcp[i + 1]
    return goals


def stage_end_points(subgoal: torch.Tensor, num_stages: int) -> torch.Tensor:
    """Per-frame stage targets (L, 3) of a successful episode (`stage_subgoals`) -> where its
    first `num_stages` stages ended (num_stages, 3): the targets in order of appearance.

    After them comes where the episode ends (its rest after the final stage), unless the final
    stage ended where the robot then rests: a stage the scene completes while the robot holds
    still (Factory Packing's conveyor carrying the packed box off) leaves one target for both.
    So an episode shows at least `num_stages` targets; whether it completed its stages is known
    from its role or its stage labels (`aed_models.train.localizer.stage_episode`), not here."""
    subgoal = torch.as_tensor(subgoal)
    change = torch.ones(len(subgoal), dtype=torch.bool)
    change[1:] = (subgoal[1:] != subgoal[:-1]).any(-1)
    points = subgoal[change]
    if len(points) < num_stages:
        raise ValueError(
            f"an episode showing {len(points)} stage targets, {num_stages} needed "
            "(is it a successful one?)"
        )
    return points[:num_stages]


CLUTTER = re.compile(r"distractor_\d+$")  # the tasks' unrelated clutter (not task objects)
PARTICLES = re.compile(r"(water)_\d+$")  # as many as the scene holds: one object, their centroid
ROBOTS = ("panda",)


def task_objects(group: Any) -> Iterator[tuple[str, str, tuple[str, ...], int]]:
    """(kind, name, bodies, joints) of every task object in a stored episode's env states: every
    actor and articulation but the robot and the clutter, sorted by name (joints: 0 for an
    actor). A scene's particles (`PARTICLES`: Move Glass Cup's water drops, whose number varies
    with the glass) are one object of many bodies, so every scene of a task has the same state."""
    states = group["env_states"]
    for kind in ("actors", "articulations"):
        objects: dict[str, list[str]] = defaultdict(list)
        for name in states.get(kind, {}):
            if name in ROBOTS or CLUTTER.match(name):
                continue
            particle = PARTICLES.match(name)
            objects[particle.group(1) if particle else name].append(name)
        for name in sorted(objects):
            bodies = tuple(sorted(objects[name]))
            joints = (states[kind][bodies[0]].shape[1] - 13) // 2 if kind == "articulations" else 0
            yield kind, name, bodies, joints


def scene_state(group: Any, stage_target: bool = True) -> np.ndarray:
    """(T + 1, D) float32: where things are at every frame of one stored episode.

    The TCP position, the stage target (`stage_subgoals`; NaN with `stage_target=False`, for an
    episode that does not do the task), then each task object's root position (the centroid of
    its bodies) and joint positions (`task_objects`). The encoder learns these from the frame
    (`aed_models.encoder`); the policies act from RGB-D alone.
    """
    tcp = group["obs/extra/tcp_pose"][()][:, :3].astype(np.float32)
    target = stage_subgoals(tcp, group["stage"][()])
    parts = [tcp, target if stage_target else np.full_like(target, np.nan)]
    for kind, _, bodies, joints in task_objects(group):
        states = [group["env_states"][kind][body][()] for body in bodies]
        state = np.mean(states, axis=0, dtype=np.float64).astype(np.float32)
        parts += [state[:, :3], state[:, 13 : 13 + joints]]
    return np.concatenate(parts, axis=1)


def scene_state_names(group: Any) -> list[str]:
    """Names of `scene_state`'s columns (e.g. `button.x`, `button.q0`, `water.z`)."""
    names = [f"tcp.{a}" for a in "xyz"] + [f"subgoal.{a}" for a in "xyz"]
    for _, name, _, joints in task_objects(group):
        names += [f"{name}.{a}" for a in "xyz"] + [f"{name}.q{i}" for i in range(joints)]
    return names


@dataclass
class FrameSequence:
    """One episode's (possibly augmented / subsampled) frames with aligned per-frame data.

    Images stay as stored (uint8 / int16) until `frames` or `pad_sequences` converts them,
    so a batch is converted once, straight into its padded tensor.
    """

    rgb: np.ndarray | None  # (L, H, W, 3) uint8 (None when only features were read)
    depth: np.ndarray | None  # (L, H, W, 1) int16 mm
    labels: torch.Tensor  # (L,) float32
    actions: torch.Tensor  # (L, A) float32
    source: torch.Tensor  # (L,) int64: index of each frame in the episode
    ref: trajectory.EpisodeRef
    proprio: torch.Tensor | None = None  # (L, PROPRIO_DIM) float32
    subgoal: torch.Tensor | None = None  # (L, 3) float32
    features: torch.Tensor | None = None  # (L, D) float32: a frozen visual head's, cached
    located: torch.Tensor | None = None  # (L, 3K) float32: the localizer's points, repeated
    action_chunks: torch.Tensor | None = None  # (L, C, A) float32: the actions from each frame on
    chunk_valid: torch.Tensor | None = None  # (L, C) bool: which of them the episode has

    def __len__(self) -> int:
        return len(self.source)

    @property
    def frames(self) -> torch.Tensor:
        """(L, 4, H, W) float32."""
        return to_frames(self.rgb, self.depth)


class EpisodeReader:
    """Reads frames of episodes lazily, keeping HDF5 handles open per process.

    A handle opened before a DataLoader forked its workers is never reused in them: on a
    new process id the cache starts empty; pickling drops it too.
    """

    def __init__(self, camera: str = "front", max_open: int = 64):
        self.camera = camera
        self.max_open = max_open
        self._files: dict[Path, Any] = {}
        self._pid = os.getpid()

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_files": {}}

    def _file(self, path: Path) -> Any:
        import h5py

        if os.getpid() != self._pid:
            self._files, self._pid = {}, os.getpid()
        if path not in self._files:
            if len(self._files) >= self.max_open:
                self._files.pop(next(iter(self._files))).close()
            self._files[path] = h5py.File(path, "r")
        return self._files[path]

    def read(
        self,
        ref: trajectory.EpisodeRef,
        indices: np.ndarray | None = None,
        images: bool = True,
        chunk: int = 1,
    ) -> FrameSequence:
        """Frames `indices` (default: all T + 1) of one episode, in that order (repeats allowed);
        `images=False` reads everything but the images. `chunk` > 1 also gives, for each frame,
        the episode's next `chunk` actions from it (`action_chunks`, `chunk_valid`), whichever
        frames were read."""
        h5 = self._file(ref.path)
        group = h5[ref.traj]
        if indices is None:
            indices = np.arange(ref.num_frames, dtype=np.int64)
        indices = np.asarray(indices, dtype=np.int64)
        if len(indices) == 0 or indices.min() < 0 or indices.max() >= ref.num_frames:
            raise IndexError(
                f"{ref.path.name}/{ref.traj}: frame indices outside 0..{ref.num_frames - 1}"
            )
        rgb = depth = None
        if images:
            if self.camera not in group["obs/sensor_data"]:
                raise KeyError(
                    f"{ref.path.name}/{ref.traj}: no frames of camera {self.camera!r} "
                    f"(recorded: {sorted(group['obs/sensor_data'])})"
                )
            camera = group[f"obs/sensor_data/{self.camera}"]
            unique, inverse = np.unique(indices, return_inverse=True)
            rgb = _read_rows(camera["rgb"], unique)[inverse]
            depth = _read_rows(camera["depth"], unique)[inverse]
        labels = frame_labels(group["error_label"][()]).astype(np.float32)[indices]
        recorded = group["actions"][()].astype(np.float32)
        actions = np.concatenate([recorded, np.zeros((1, recorded.shape[1]), np.float32)])[indices]
        action_chunks = chunk_valid = None
        if chunk > 1:
            later = indices[:, None] + np.arange(chunk)[None]  # (L, C)
            valid = later < len(recorded)
            action_chunks = torch.from_numpy(
                recorded[later.clip(max=len(recorded) - 1)] * valid[..., None]
            )
            chunk_valid = torch.from_numpy(valid)
        proprio = subgoal = None
        if (
            "obs/extra/tcp_pose" in group and "obs/agent/qpos" in group
        ):  # every rgbd collection has both
            tcp_pose = group["obs/extra/tcp_pose"][()]
            proprio = torch.from_numpy(
                proprio_from_obs(tcp_pose, group["obs/agent/qpos"][()])[indices]
            )
            subgoal = torch.from_numpy(
                stage_subgoals(tcp_pose[:, :3].astype(np.float32), group["stage"][()])[indices]
            )
        return FrameSequence(
            rgb,
            depth,
            torch.from_numpy(labels),
            torch.from_numpy(actions),
            torch.from_numpy(indices),
            ref,
            proprio,
            subgoal,
            action_chunks=action_chunks,
            chunk_valid=chunk_valid,
        )

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        self._files.clear()


def _read_rows(dataset: Any, rows: np.ndarray) -> np.ndarray:
    """dataset[rows] for sorted unique rows, one row at a time.

    Images are chunked one frame per chunk, so a row read is a chunk read; h5py's fancy
    indexing (`dataset[rows]`) was 40x slower here (32 of 85 frames: 0.82 s vs 0.019 s) and
    even a full slab read was slower than reading its rows one by one.
    """
    out = np.empty((len(rows), *dataset.shape[1:]), dtype=dataset.dtype)
    for i, row in enumerate(rows):
        dataset.read_direct(out, np.s_[int(row)], np.s_[i])
    return out


def pad_sequences(seqs: Sequence[FrameSequence]) -> dict[str, torch.Tensor]:
    """Pad to the longest: frames (B, L, 4, H, W), labels (B, L), actions (B, L, A), lengths (B,),
    mask (B, L), source (B, L) (each frame's index in its episode), and proprio
    (B, L, PROPRIO_DIM), subgoal (B, L, 3), located (B, L, 3K) and action_chunks (B, L, C, A)
    with chunk_valid (B, L, C) when every sequence has them.
    Sequences read without images give their cached `features` (B, L, D) instead of frames."""
    if not seqs:
        return {}
    lengths = torch.tensor([len(s) for s in seqs], dtype=torch.int64)
    longest = int(lengths.max())
    labels = torch.zeros(len(seqs), longest)
    actions = torch.zeros(len(seqs), longest, seqs[0].actions.shape[1])
    source = torch.zeros(len(seqs), longest, dtype=torch.int64)
    for i, s in enumerate(seqs):
        n = len(s)
        labels[i, :n], actions[i, :n], source[i, :n] = s.labels, s.actions, s.source
    mask = torch.arange(longest)[None] < lengths[:, None]
    batch = {
        "labels": labels,
        "actions": actions,
        "lengths": lengths,
        "mask": mask,
        "source": source,
    }
    if seqs[0].rgb is not None:
        height, width = seqs[0].rgb.shape[1:3]
        frames = torch.empty((len(seqs), longest, 4, height, width), dtype=torch.float32)
        for i, s in enumerate(seqs):
            to_frames(s.rgb, s.depth, out=frames[i, : len(s)])
            frames[i, len(s) :] = 0.0
        batch["frames"] = frames
    for key in ("features", "proprio", "subgoal", "located", "action_chunks", "chunk_valid"):
        if all(getattr(s, key) is not None for s in seqs):
            shape, dtype = getattr(seqs[0], key).shape[1:], getattr(seqs[0], key).dtype
            dtype = torch.bool if dtype == torch.bool else torch.float32
            batch[key] = torch.zeros(len(seqs), longest, *shape, dtype=dtype)
            for i, s in enumerate(seqs):
                batch[key][i, : len(s)] = getattr(s, key)
    return batch


def load_episodes(
    roots: Path | str | Sequence[Path | str],
    split: str | None = "base",
    check: trajectory.Check = "quick",
) -> list[trajectory.EpisodeRef]:
    """Every episode of one or several collection folders (validated), optionally one split."""
    roots = [roots] if isinstance(roots, (str, Path)) else list(roots)
    refs = [e for root in roots for e in trajectory.scan_collection(Path(root), check).episodes()]
    return [e for e in refs if split is None or e.split == split]


class EnvironmentIterations(Dataset):
    """One item = one training iteration: episodes sampled from one environment.

    Items are indexed by `(epoch, position)` (see `EnvironmentSampler`), and every draw is
    seeded by (seed, epoch, position), so batches are the same with any number of workers.
    A plain int index means epoch 0.

    Args:
        episodes: episode refs (see `load_episodes`); environments are grouped by index.
        composition: episodes per iteration, or a key of `COMPOSITIONS`.
        camera: which camera's frames.
        augment: applied to agent rollouts only (demonstrations are never augmented).
        max_frames: cap each sequence at this many frames (evenly subsampled).
        rollout_frames: how agent rollouts are capped: `even` (evenly spread, first and last
            kept) or `random` (a fresh sorted random subset every draw: more distinct frames
            per epoch for a per-frame model such as NaiveDC). Demonstrations are always even.
        demos: which demonstrations to draw: optimal, suboptimal, or any.
        seed: root seed of the draws.
        features: per episode (keyed by `(str(path), traj)`), a frozen visual head's cached
            features (T + 1, D): sequences then carry them instead of images.
        located: per agent episode (same keys), where a target localizer placed its stage
            targets (K, 3): its sequences carry them at every frame (`located`).
        action_chunk: agent sequences also carry each frame's next `action_chunk` actions
            (`action_chunks`, `chunk_valid`), for a policy that predicts them (1: none).
    """

    def __init__(
        self,
        episodes: Sequence[trajectory.EpisodeRef],
        composition: Composition | str = "detector",
        camera: str = "front",
        augment: RolloutAugment | None = None,
        max_frames: int | None = None,
        demos: Literal["optimal", "suboptimal", "any"] = "optimal",
        seed: int = 0,
        rollout_frames: Literal["even", "random"] = "even",
        features: Mapping[tuple[str, str], np.ndarray] | None = None,
        located: Mapping[tuple[str, str], np.ndarray] | None = None,
        action_chunk: int = 1,
    ):
        if isinstance(composition, str):
            if composition not in COMPOSITIONS:
                raise ValueError(f"composition={composition!r}: known {sorted(COMPOSITIONS)}")
            composition = COMPOSITIONS[composition]
        if max_frames is not None and max_frames < 2:
            raise ValueError(f"max_frames={max_frames}: must be >= 2 (first and last frame)")
        if rollout_frames not in ("even", "random"):
            raise ValueError(f"rollout_frames={rollout_frames!r}: even or random")
        self.rollout_frames = rollout_frames
        self.composition = composition
        self.augment = augment
        self.max_frames = max_frames
        self.seed = seed
        self.features = features
        self.located = located
        if action_chunk < 1:
            raise ValueError(f"action_chunk={action_chunk}: must be >= 1")
        self.action_chunk = action_chunk
        self.reader = EpisodeReader(camera)
        self.pools = _group(episodes, demos)
        self.env_indices = sorted(self.pools)
        if not self.env_indices:
            raise ValueError("no episodes: is the collection empty, or of another split?")
        self._check_pools()

    def _check_pools(self) -> None:
        wanted = {
            "demo": self.composition.num_demos,
            "agent_success": self.composition.num_successes,
            "agent_failure": self.composition.num_failures,
        }
        for env_index, pool in self.pools.items():
            for role, n in wanted.items():
                if n and not pool[role]:
                    raise ValueError(
                        f"environment {env_index} has no {role} episodes, the composition asks {n}"
                    )
                if 0 < len(pool[role]) < n:
                    logger.info(
                        "environment %d: %d %s episodes < %d per iteration, "
                        "sampled with replacement",
                        env_index,
                        len(pool[role]),
                        role,
                        n,
                    )

    def __len__(self) -> int:
        return len(self.env_indices)

    def __getitem__(self, item: int | tuple[int, int]) -> dict[str, Any]:
        epoch, position = (0, item) if isinstance(item, int) else item
        env_index = self.env_indices[position]
        rng = np.random.default_rng([self.seed, epoch, position])
        pool = self.pools[env_index]
        demos = [
            self._sequence(ref, rng, augment=False)
            for ref in _draw(pool["demo"], self.composition.num_demos, rng)
        ]
        rollouts = [
            self._sequence(ref, rng, augment=True)
            for role, n in (
                ("agent_success", self.composition.num_successes),
                ("agent_failure", self.composition.num_failures),
            )
            for ref in _draw(pool[role], n, rng)
        ]
        batch = {
            "env_index": env_index,
            "epoch": epoch,
            "demos": pad_sequences(demos),
            "rollouts": pad_sequences(rollouts),
        }
        if rollouts:
            batch["rollouts"]["is_failure"] = torch.tensor(
                [s.ref.role == "agent_failure" for s in rollouts]
            )
        return batch

    def _sequence(
        self, ref: trajectory.EpisodeRef, rng: np.random.Generator, augment: bool
    ) -> FrameSequence:
        if augment and self.augment is not None:
            indices = self.augment.indices(ref.num_frames, rng)
        else:
            indices = np.arange(ref.num_frames, dtype=np.int64)
        if (
            ref.role != "demo"
            and self.rollout_frames == "random"
            and self.max_frames
            and len(indices) > self.max_frames
        ):
            indices = indices[np.sort(rng.choice(len(indices), self.max_frames, replace=False))]
        else:
            indices = subsample(indices, self.max_frames)
        chunk = 1 if ref.role == "demo" else self.action_chunk
        if self.features is None:
            seq = self.reader.read(ref, indices, chunk=chunk)
        else:
            seq = self.reader.read(ref, indices, images=False, chunk=chunk)
            seq.features = torch.from_numpy(self.features[str(ref.path), ref.traj][indices])
        if self.located is not None and ref.role != "demo":
            points = torch.from_numpy(self.located[str(ref.path), ref.traj]).reshape(1, -1)
            seq.located = points.float().expand(len(indices), -1).clone()
        return seq


def _group(
    episodes: Sequence[trajectory.EpisodeRef], demos: str
) -> dict[int, dict[str, list[trajectory.EpisodeRef]]]:
    if demos not in ("optimal", "suboptimal", "any"):
        raise ValueError(f"demos={demos!r}: optimal, suboptimal or any")
    pools: dict[int, dict[str, list[trajectory.EpisodeRef]]] = defaultdict(
        lambda: defaultdict(list)
    )
    for ref in episodes:
        if ref.role == "demo" and demos != "any" and ref.suboptimal != (demos == "suboptimal"):
            continue
        pools[ref.env_index][ref.role].append(ref)
    return pools


def _draw(
    pool: list[trajectory.EpisodeRef], n: int, rng: np.random.Generator
) -> list[trajectory.EpisodeRef]:
    if n == 0:
        return []
    picks = rng.choice(len(pool), size=n, replace=len(pool) < n)
    return [pool[i] for i in picks]


class EnvironmentSampler(Sampler):
    """Yields `(epoch, position)`: every epoch visits each environment once, shuffled by
    (seed, epoch).

    Use with
    `DataLoader(dataset, sampler=EnvironmentSampler(len(dataset), epochs), batch_size=None)`.
    """

    def __init__(
        self,
        num_envs: int,
        epochs: int = 1,
        seed: int = 0,
        shuffle: bool = True,
        start_epoch: int = 0,
    ):
        if num_envs < 1 or epochs < 1:
            raise ValueError(f"num_envs={num_envs}, epochs={epochs}: both must be >= 1")
        self.num_envs, self.epochs, self.seed, self.shuffle, self.start_epoch = (
            num_envs,
            epochs,
            seed,
            shuffle,
            start_epoch,
        )

    def __iter__(self) -> Iterator[tuple[int, int]]:
        for epoch in range(self.start_epoch, self.start_epoch + self.epochs):
            order = np.arange(self.num_envs)
            if self.shuffle:
                order = np.random.default_rng([self.seed, epoch]).permutation(self.num_envs)
            for position in order:
                yield epoch, int(position)

    def __len__(self) -> int:
        return self.num_envs * self.epochs


class EpisodeDataset(Dataset):
    """One item = one whole episode (offline scoring, evaluation), optionally capped in frames."""

    def __init__(
        self,
        episodes: Sequence[trajectory.EpisodeRef],
        camera: str = "front",
        max_frames: int | None = None,
    ):
        self.episodes = list(episodes)
        self.max_frames = max_frames
        self.reader = EpisodeReader(camera)

    def __len__(self) -> int:
        return len(self.episodes)

    def __getitem__(self, i: int) -> FrameSequence:
        ref = self.episodes[i]
        return self.reader.read(ref, subsample(np.arange(ref.num_frames), self.max_frames))


def collate_episodes(seqs: list[FrameSequence]) -> dict[str, Any]:
    """DataLoader `collate_fn` for `EpisodeDataset`: padded tensors plus the refs."""
    return {**pad_sequences(seqs), "refs": [s.ref for s in seqs]}

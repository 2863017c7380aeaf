"""The frozen policy's per-frame features of stored episodes, computed once and kept on disk.

PrObe and RND-OE train on the policy's history features f_h and task embedding f_zeta, not on
images, so the features of every base agent rollout are computed once per key:

    <root>/<policy sha256[:16]>/seed<seed>-demos<num_demos>/<shard stem>.npz

one file per shard, written atomically: per episode history (T+1, Dh), task (T+1, Dz) and
labels (T+1,), and a `meta` naming everything they depend on (the policy, the demonstrations'
draw, the shard's size and mtime, which demonstrations conditioned the policy: one fixed draw
per environment). A file that does not match is stale, one that does not load corrupt: `build`
recomputes both under the folder's lock (a second builder waits), `load` refuses them.
Augmentation then permutes the cached sequences (`FeatureIterations`): for DCT and SCAN an
approximation of re-running the history over permuted frames, with no image work.
"""

from __future__ import annotations

import json
import logging
import zipfile
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from aed_models.augment import RolloutAugment
from aed_models.data import (
    COMPOSITIONS,
    Composition,
    EpisodeReader,
    _draw,
    _group,
    pad_sequences,
    subsample,
)
from aed_tasks import trajectory
from aed_tasks.locks import folder_lock

logger = logging.getLogger(__name__)

ROLLOUT_ROLES = ("agent_success", "agent_failure")


class FeatureCacheError(ValueError):
    """A cache file that is missing, stale or corrupt, or an environment without the
    demonstrations to compute it (the message names the file or environment, and why)."""


@dataclass
class CachedEpisode:
    history: np.ndarray  # (T+1, Dh) float32
    task: np.ndarray  # (T+1, Dz) float32
    labels: np.ndarray  # (T+1,) float32


def _shard_stamp(path: Path) -> dict[str, int]:
    stat = path.stat()
    return {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


class FeatureCache:
    """Policy features of episodes, keyed by (shard file, traj id), for one policy checkpoint
    conditioned on one draw of demonstrations.

    Args:
        root: the features folder, e.g. `runs/<task>/features`.
        policy_sha256: sha256 of the policy checkpoint file (64 hex digits).
        max_shards_in_memory: shards kept in memory after reading (least recently used out).
        seed: seeds each environment's draw of conditioning demonstrations.
        num_demos: demonstrations drawn per environment.
    """

    def __init__(
        self,
        root: Path | str,
        policy_sha256: str,
        max_shards_in_memory: int = 16,
        *,
        seed: int = 0,
        num_demos: int = 5,
    ):
        if len(policy_sha256) != 64 or any(c not in "0123456789abcdef" for c in policy_sha256):
            raise ValueError(f"policy_sha256={policy_sha256!r}: expected 64 lowercase hex digits")
        self.root = Path(root)
        self.policy_sha256 = policy_sha256
        self.max_shards_in_memory = max_shards_in_memory
        self._shards: OrderedDict[Path, dict[str, CachedEpisode]] = OrderedDict()  # LRU first
        self._set_key(seed, num_demos)

    def _set_key(self, seed: int, num_demos: int) -> None:
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ValueError(f"seed={seed!r}: must be an integer")
        if isinstance(num_demos, bool) or not isinstance(num_demos, int) or num_demos < 1:
            raise ValueError(f"num_demos={num_demos!r}: must be an integer >= 1")
        self.seed, self.num_demos = seed, num_demos
        self._shards = OrderedDict()

    @property
    def dir(self) -> Path:
        """This key's folder: `<root>/<policy sha256[:16]>/seed<seed>-demos<num_demos>`."""
        return self.root / self.policy_sha256[:16] / f"seed{self.seed}-demos{self.num_demos}"

    def __getstate__(self) -> dict[str, Any]:  # DataLoader workers start with an empty memory
        return {**self.__dict__, "_shards": OrderedDict()}

    def path_for(self, shard: Path) -> Path:
        return self.dir / f"{Path(shard).stem}.npz"

    # -- reading ------------------------------------------------------------------------------
    def _read(self, shard: Path, refs: Sequence[trajectory.EpisodeRef]) -> dict[str, CachedEpisode]:
        """The cached episodes of one shard, checked against `refs`; raises FeatureCacheError."""
        path = self.path_for(shard)
        if not path.is_file():
            raise FeatureCacheError(f"{path}: not cached yet (build the cache first)")
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                arrays = {k: data[k] for k in data.files if k != "meta"}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as e:
            raise FeatureCacheError(f"{path}: corrupt cache file ({type(e).__name__}: {e})") from e
        if not isinstance(meta, dict):
            raise FeatureCacheError(f"{path}: corrupt cache file (its meta is not a JSON object)")
        problem = self._stale(meta, shard, refs)
        if problem:
            raise FeatureCacheError(f"{path}: stale cache file ({problem})")
        episodes = {}
        for ref in refs:
            try:
                ep = CachedEpisode(
                    arrays[f"{ref.traj}/history"],
                    arrays[f"{ref.traj}/task"],
                    arrays[f"{ref.traj}/labels"],
                )
            except KeyError as e:
                raise FeatureCacheError(
                    f"{path}: corrupt cache file (no arrays for {ref.traj})"
                ) from e
            if not (len(ep.history) == len(ep.task) == len(ep.labels) == ref.num_frames):
                raise FeatureCacheError(
                    f"{path}: corrupt cache file ({ref.traj} arrays do not have "
                    f"{ref.num_frames} frames)"
                )
            episodes[ref.traj] = ep
        return episodes

    def _stale(
        self, meta: dict[str, Any], shard: Path, refs: Sequence[trajectory.EpisodeRef]
    ) -> str | None:
        if meta.get("policy_sha256") != self.policy_sha256:
            return (
                f"made with policy {str(meta.get('policy_sha256'))[:16]}, "
                f"not {self.policy_sha256[:16]}"
            )
        for name in ("seed", "num_demos"):
            if meta.get(name) != getattr(self, name):
                return f"made with {name}={meta.get(name)!r}, not {getattr(self, name)!r}"
        if meta.get("shard") != Path(shard).name or meta.get("stamp") != _shard_stamp(Path(shard)):
            return f"episode shard {Path(shard).name} changed since it was cached"
        frames = meta.get("num_frames", {})
        for ref in refs:
            if frames.get(ref.traj) != ref.num_frames:
                return f"{ref.traj} is not cached with {ref.num_frames} frames"
        return None

    def load(self, ref: trajectory.EpisodeRef) -> CachedEpisode:
        """One episode's cached features (the most recently used shards stay in memory)."""
        shard = Path(ref.path)
        if shard not in self._shards or ref.traj not in self._shards[shard]:
            self._shards[shard] = {**self._shards.get(shard, {}), **self._read(shard, [ref])}
        self._shards.move_to_end(shard)
        while len(self._shards) > self.max_shards_in_memory:
            self._shards.popitem(last=False)
        return self._shards[shard][ref.traj]

    def check(self, refs: Sequence[trajectory.EpisodeRef]) -> None:
        """Read and check every shard of `refs` once (fails early, before training starts)."""
        for shard, group in _by_shard(refs).items():
            self._read(shard, group)

    # -- writing ------------------------------------------------------------------------------
    def build(
        self,
        episodes: Sequence[trajectory.EpisodeRef],
        policy: Any,
        num_demos: int | None = None,
        seed: int | None = None,
        camera: str = "front",
        progress: bool = False,
    ) -> int:
        """Compute and write the features of every agent rollout in `episodes` whose shard is
        not cached, stale or corrupt. Returns the number of shards written.

        `num_demos` and `seed`, when given, re-key the cache (its `dir` follows). The folder is
        locked while it is written: another process building the same key waits, then reads it.
        """
        self._set_key(
            self.seed if seed is None else seed, self.num_demos if num_demos is None else num_demos
        )
        rollouts = [e for e in episodes if e.role in ROLLOUT_ROLES]
        todo = self._todo(_by_shard(rollouts), quiet=True)
        if not todo:
            return 0
        with folder_lock(self.dir, wait=True):  # checked again: another process may have written
            return self._write(self._todo(todo, quiet=False), episodes, policy, camera, progress)

    def _todo(
        self, shards: dict[Path, list[trajectory.EpisodeRef]], quiet: bool
    ) -> dict[Path, list[trajectory.EpisodeRef]]:
        """The shards among `shards` that are not cached, or stale, or corrupt."""
        todo = {}
        for shard, refs in shards.items():
            try:
                self._read(shard, refs)
            except FeatureCacheError as e:
                if not quiet and self.path_for(shard).exists():
                    logger.warning("recomputing features: %s", e)
                todo[shard] = refs
        return todo

    def _write(
        self,
        todo: dict[Path, list[trajectory.EpisodeRef]],
        episodes: Sequence[trajectory.EpisodeRef],
        policy: Any,
        camera: str,
        progress: bool,
    ) -> int:
        """Compute the features of `todo`'s shards and write one file per shard."""
        if not todo:
            return 0
        num_demos, seed = self.num_demos, self.seed
        demo_pools = _group(episodes, "optimal")
        device = next(iter(policy.parameters())).device
        reader = EpisodeReader(camera)
        demo_cache: dict[int, tuple[dict[str, torch.Tensor], list[str]]] = {}
        from tqdm.auto import tqdm

        try:
            for shard, refs in tqdm(
                todo.items(), desc="policy features", unit="shard", disable=not progress
            ):
                arrays: dict[str, np.ndarray] = {}
                used_demos: dict[str, list[str]] = {}
                for ref in refs:
                    if ref.env_index not in demo_cache:
                        demo_cache[ref.env_index] = self._demos(
                            demo_pools, ref.env_index, num_demos, seed, reader, device
                        )
                    demos, demo_names = demo_cache[ref.env_index]
                    seq = reader.read(ref)
                    mask = torch.ones(1, len(seq), dtype=torch.bool, device=device)
                    with torch.no_grad():
                        proprio = None if seq.proprio is None else seq.proprio[None].to(device)
                        feats = policy.features(
                            seq.frames[None].to(device), mask, demos, proprio=proprio
                        )
                    arrays[f"{ref.traj}/history"] = feats.history[0].float().cpu().numpy()
                    arrays[f"{ref.traj}/task"] = feats.task[0].float().cpu().numpy()
                    arrays[f"{ref.traj}/labels"] = seq.labels.float().numpy()
                    used_demos[ref.traj] = demo_names
                meta = {
                    "policy_sha256": self.policy_sha256,
                    "shard": shard.name,
                    "stamp": _shard_stamp(shard),
                    "num_frames": {r.traj: r.num_frames for r in refs},
                    "demos": used_demos,
                    "num_demos": num_demos,
                    "seed": seed,
                }
                trajectory.write_npz_atomic(self.path_for(shard), arrays, meta)
                self._shards.pop(shard, None)
        finally:
            reader.close()
        return len(todo)

    @staticmethod
    def _demos(
        pools: dict,
        env_index: int,
        num_demos: int,
        seed: int,
        reader: EpisodeReader,
        device: torch.device,
    ) -> tuple[dict[str, torch.Tensor], list[str]]:
        pool = pools.get(env_index, {}).get("demo", [])
        if not pool:
            raise FeatureCacheError(
                f"environment {env_index} has no optimal demonstration to condition the policy on"
            )
        refs = _draw(pool, num_demos, np.random.default_rng([seed, env_index]))
        padded = pad_sequences([reader.read(r) for r in refs])
        demos = {k: padded[k].to(device) for k in ("frames", "mask", "proprio") if k in padded}
        return demos, [f"{r.path.name}/{r.traj}" for r in refs]


def _by_shard(refs: Sequence[trajectory.EpisodeRef]) -> dict[Path, list[trajectory.EpisodeRef]]:
    out: dict[Path, list[trajectory.EpisodeRef]] = {}
    for ref in refs:
        out.setdefault(Path(ref.path), []).append(ref)
    return out


class FeatureIterations(Dataset):
    """`EnvironmentIterations` over cached policy features instead of frames.

    One item = one iteration on one environment: the composition's rollouts (demonstrations
    are drawn too, to keep the random stream identical to the frame dataset's, but reach the
    detector through the cached task embedding only). Rollouts are augmented with the same
    `RolloutAugment.indices` and subsampled with the same `max_frames` rule as frames.

    Item: {"env_index", "epoch", "rollouts": {mask, lengths, labels, is_failure},
    "features": (history (B, T, Dh), task (B, T, Dz))}, padded with zeros.
    """

    def __init__(
        self,
        episodes: Sequence[trajectory.EpisodeRef],
        cache: FeatureCache,
        composition: Composition | str = "detector",
        augment: RolloutAugment | None = None,
        max_frames: int | None = None,
        seed: int = 0,
    ):
        if isinstance(composition, str):
            if composition not in COMPOSITIONS:
                raise ValueError(f"composition={composition!r}: known {sorted(COMPOSITIONS)}")
            composition = COMPOSITIONS[composition]
        if max_frames is not None and max_frames < 2:
            raise ValueError(f"max_frames={max_frames}: must be >= 2 (first and last frame)")
        self.composition, self.cache, self.augment, self.max_frames, self.seed = (
            composition,
            cache,
            augment,
            max_frames,
            seed,
        )
        self.pools = _group(episodes, "optimal")
        self.env_indices = sorted(self.pools)
        if not self.env_indices:
            raise ValueError("no episodes: is the collection empty, or of another split?")
        for env_index, pool in self.pools.items():
            for role, n in (
                ("agent_success", composition.num_successes),
                ("agent_failure", composition.num_failures),
            ):
                if n and not pool[role]:
                    raise ValueError(
                        f"environment {env_index} has no {role} episodes, the composition asks {n}"
                    )
        cache.check([e for e in episodes if e.role in ROLLOUT_ROLES])

    def __len__(self) -> int:
        return len(self.env_indices)

    def __getitem__(self, item: int | tuple[int, int]) -> dict[str, Any]:
        epoch, position = (0, item) if isinstance(item, int) else item
        env_index = self.env_indices[position]
        rng = np.random.default_rng([self.seed, epoch, position])
        pool = self.pools[env_index]
        if pool[
            "demo"
        ]:  # drawn and discarded: keeps the random stream equal to EnvironmentIterations'
            _draw(pool["demo"], self.composition.num_demos, rng)
        seqs, failures = [], []
        for role, n in (
            ("agent_success", self.composition.num_successes),
            ("agent_failure", self.composition.num_failures),
        ):
            for ref in _draw(
                pool[role], n, rng
            ):  # draw, then augment, in EnvironmentIterations' order
                indices = np.arange(ref.num_frames, dtype=np.int64)
                if self.augment is not None:
                    indices = self.augment.indices(ref.num_frames, rng)
                keep = subsample(indices, self.max_frames)
                ep = self.cache.load(ref)
                seqs.append((ep.history[keep], ep.task[keep], ep.labels[keep], keep))
                failures.append(role == "agent_failure")
        return {"env_index": env_index, "epoch": epoch, **_pad_features(seqs, failures)}


def _pad_features(
    seqs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], failures: list[bool]
) -> dict[str, Any]:
    """Padded (history, task, labels, source frame index) sequences: the rollouts dict and
    features."""
    lengths = torch.tensor([len(s[0]) for s in seqs], dtype=torch.int64)
    longest = int(lengths.max())
    b = len(seqs)
    history = torch.zeros(b, longest, seqs[0][0].shape[1])
    task = torch.zeros(b, longest, seqs[0][1].shape[1])
    labels = torch.zeros(b, longest)
    source = torch.zeros(b, longest, dtype=torch.int64)
    for i, (h, z, y, s) in enumerate(seqs):
        n = len(h)
        history[i, :n], task[i, :n], labels[i, :n] = (
            torch.from_numpy(h),
            torch.from_numpy(z),
            torch.from_numpy(y),
        )
        source[i, :n] = torch.from_numpy(np.asarray(s, dtype=np.int64))
    mask = torch.arange(longest)[None] < lengths[:, None]
    rollouts = {
        "mask": mask,
        "lengths": lengths,
        "labels": labels,
        "is_failure": torch.tensor(failures),
        "source": source,
    }
    return {"rollouts": rollouts, "features": (history, task)}

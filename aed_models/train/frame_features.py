"""A frozen visual head's per-frame features of stored episodes, computed once and kept on disk.

The mini policies' visual head is the task's scene encoder, frozen, so every training epoch
would encode the same frames again. They are encoded once per (encoder, collection):

    <root>/<encoder sha256[:16]>/<collection key>/<shard stem>.npz

one file per episode shard (`traj_<i>`: (T + 1, D) float32, and `meta`: the encoder's sha256,
the shard's size and mtime), written atomically; episodes missing from a file are added to it.
A file whose meta no longer matches is recomputed; the collection key is a hash of the
collection folder's absolute path. One process encodes into a folder at a time (its lock); a
second waits, then reads what the first wrote.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from aed_models.data import EpisodeReader
from aed_tasks import trajectory
from aed_tasks.locks import folder_lock

logger = logging.getLogger(__name__)

Features = dict[tuple[str, str], np.ndarray]


def shard_meta(h5_path: Path, encoder_sha: str) -> dict:
    stat = h5_path.stat()
    return {"encoder": encoder_sha, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def read_cached(path: Path, meta: dict) -> dict[str, np.ndarray]:
    """Every episode's features cached in `path` ({} when missing, stale or unreadable)."""
    if not path.is_file():
        return {}
    try:
        with np.load(path) as npz:
            if json.loads(str(npz["meta"])) != meta:
                return {}
            return {key: npz[key] for key in npz.files if key != "meta"}
    except (OSError, ValueError, KeyError) as e:
        logger.warning("%s: unreadable feature cache (%s), recomputing", path, e)
        return {}


@torch.no_grad()
def encode_episode(
    visual: nn.Module, reader: EpisodeReader, ref: trajectory.EpisodeRef, batch: int = 128
) -> np.ndarray:
    """(T + 1, D) float32 features of every frame of one episode."""
    out = []
    for start in range(0, ref.num_frames, batch):
        indices = np.arange(start, min(start + batch, ref.num_frames))
        out.append(visual(reader.read(ref, indices).frames).numpy())
    return np.concatenate(out).astype(np.float32)


def frame_features(
    visual: nn.Module,
    encoder_sha: str,
    episodes: Sequence[trajectory.EpisodeRef],
    root: Path,
    progress: bool = True,
) -> Features:
    """Features of every frame of `episodes`, keyed by `(str(path), traj)`: read from the cache
    under `root`, encoded (and cached) where missing or stale."""
    if not episodes:
        return {}
    visual.eval()
    collection = str(Path(episodes[0].path).parent.resolve())
    folder = root / encoder_sha[:16] / hashlib.sha256(collection.encode()).hexdigest()[:12]
    by_shard: dict[Path, list[trajectory.EpisodeRef]] = defaultdict(list)
    for ref in episodes:
        by_shard[Path(ref.path)].append(ref)
    features, encoded = {}, 0

    def missing() -> dict[Path, list[trajectory.EpisodeRef]]:
        """Store what the cache holds in `features`; return the episodes it lacks, by shard."""
        lacking = defaultdict(list)
        for h5_path, refs in by_shard.items():
            cached = read_cached(folder / f"{h5_path.stem}.npz", shard_meta(h5_path, encoder_sha))
            for ref in refs:
                if ref.traj in cached:
                    features[(str(h5_path), ref.traj)] = cached[ref.traj]
                else:
                    lacking[h5_path].append(ref)
        return lacking

    if missing():
        with folder_lock(folder, wait=True):  # one encoder per folder; read again once held
            reader = EpisodeReader()
            for h5_path, refs in tqdm(
                sorted(missing().items()), desc="features", disable=not progress
            ):
                path, meta = folder / f"{h5_path.stem}.npz", shard_meta(h5_path, encoder_sha)
                new = {ref.traj: encode_episode(visual, reader, ref) for ref in refs}
                trajectory.write_npz_atomic(path, {**read_cached(path, meta), **new}, meta)
                features.update({(str(h5_path), traj): f for traj, f in new.items()})
                encoded += len(refs)
            reader.close()
    logger.info("features of %d episodes (%d encoded) in %s", len(episodes), encoded, folder)
    return features

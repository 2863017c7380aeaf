"""A frozen visual head's per-frame features of stored episodes, computed once and kept on disk.

The mini policies' visual head is the task's scene encoder, frozen, so every training epoch
would encode the same frames again. They are encoded once per (encoder, collection):

    <root>/<encoder sha256[:16]>/<collection key>/<shard stem>.npz

one file per episode shard (`traj_<i>`: (T + 1, D) float32, and `meta`: the encoder's sha256,
the shard's size and mtime), written atomically. A file whose meta no longer matches is
recomputed; the collection key is a hash of the collection folder's absolute path.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from aed_models.data import EpisodeReader
from aed_tasks import trajectory

logger = logging.getLogger(__name__)

Features = dict[tuple[str, str], np.ndarray]


def shard_meta(h5_path: Path, encoder_sha: str) -> dict:
    stat = h5_path.stat()
    return {"encoder": encoder_sha, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def read_cached(path: Path, meta: dict, trajs: Sequence[str]) -> dict[str, np.ndarray] | None:
    """The cached features of `trajs`, or None when the file is missing, stale or unreadable."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as npz:
            if json.loads(str(npz["meta"])) != meta:
                return None
            return {traj: npz[traj] for traj in trajs}
    except (OSError, ValueError, KeyError) as e:
        logger.warning("%s: unreadable feature cache (%s), recomputing", path, e)
        return None


def write_cached(path: Path, meta: dict, features: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, meta=np.array(json.dumps(meta)), **features)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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
    reader, features, encoded = EpisodeReader(), {}, 0
    for h5_path, refs in tqdm(sorted(by_shard.items()), desc="features", disable=not progress):
        path = folder / f"{h5_path.stem}.npz"
        meta = shard_meta(h5_path, encoder_sha)
        trajs = [ref.traj for ref in refs]
        cached = read_cached(path, meta, trajs)
        if cached is None:
            cached = {ref.traj: encode_episode(visual, reader, ref) for ref in refs}
            write_cached(path, meta, cached)
            encoded += len(refs)
        features.update({(str(h5_path), traj): cached[traj] for traj in trajs})
    reader.close()
    logger.info("features of %d episodes (%d encoded) in %s", len(episodes), encoded, folder)
    return features

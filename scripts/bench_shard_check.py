"""What verifying shards costs readers: a collection scanned with each `trajectory.Check`.

- size: json, recorded h5 size and episode groups (what readers did before);
- quick, first read in a process: the same plus every h5's sha256 (what a reader pays once);
- quick, again in that process: the verification reused (path, inode, size and mtime unchanged);
- full: the sha256 recomputed on every read (what `aed collect` does before it writes).

Without `--collection` it writes a synthetic one of realistic size first: `--episodes`
episodes of `--steps` steps in shards of `--shard-size`, each frame 160x120 RGB-D compressed to
about `--frame-kib` KiB (the README's measured 22 KiB per stored frame), with actions, labels,
proprioception and env states like `aed collect`'s. Files are in the page cache (just written
or read by the first run): the numbers are warm-cache ones. Medians over `--runs` runs, the
four scans alternated within each run; writes JSON and prints a Markdown table.

    python scripts/bench_shard_check.py                       # 350 episodes, 5 runs
    python scripts/bench_shard_check.py --collection runs/PickPlace/data/base
"""

from __future__ import annotations

import json
import logging
import platform
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import tyro

from aed_eval.logs import setup_logging
from aed_tasks import trajectory
from aed_tasks.episode import Episode

logger = logging.getLogger("bench_shard_check")
H, W = 120, 160


@dataclass
class Config:
    collection: Path | None = None
    """An existing collection to scan (default: write a synthetic one, deleted afterwards)."""
    episodes: int = 350
    """Synthetic: episodes (the issue's collection size)."""
    steps: int = 115
    """Synthetic: steps per episode (Pick & Place agent successes: median 114.5)."""
    shard_size: int = 10
    """Synthetic: episodes per shard (`aed collect`'s default)."""
    frame_kib: float = 22.0
    """Synthetic: stored bytes per frame, KiB."""
    runs: int = 5
    """Timed runs; medians are reported."""
    scratch: Path | None = None
    """Synthetic: where to write it (default: a temporary folder)."""
    out: Path = Path("results/bench_shard_check.json")


def synthetic_episode(rng: np.random.Generator, env_index: int, k: int, steps: int, kib: float):
    """One agent success with incompressible bytes filling `kib` KiB of each frame."""
    rgb = np.zeros((steps + 1, H, W, 3), np.uint8)
    noise = min(int(kib * 1024), rgb[0].size)
    rgb.reshape(steps + 1, -1)[:, :noise] = rng.integers(0, 256, (steps + 1, noise), np.uint8)
    depth = np.full((steps + 1, H, W, 1), 800, np.int16)
    episode = Episode(
        env_id="AED-PickPlace-base",
        task="PickPlace",
        split="base",
        env_index=env_index,
        seed=k,
        demonstrator=False,
        control_mode="pd_ee_delta_pos",
        actions=rng.normal(size=(steps, 4)).astype(np.float32),
        success=np.arange(steps) == steps - 1,
        fail=np.zeros(steps, bool),
        stage=np.zeros(steps, np.int16),
        error_label=np.zeros(steps, np.uint8),
    )
    recorded = trajectory.RecordedSteps(
        obs={
            "agent": {"qpos": rng.normal(size=(steps + 1, 9)).astype(np.float32)},
            "extra": {"tcp_pose": rng.normal(size=(steps + 1, 7)).astype(np.float32)},
            "sensor_data": {"front": {"rgb": rgb, "depth": depth}},
        },
        env_states={"actors": {f"obj{i}": rng.normal(size=(steps + 1, 13)) for i in range(4)}},
        terminated=np.zeros(steps, bool),
        truncated=np.zeros(steps, bool),
        rewards=np.zeros(steps, np.float32),
        reset_kwargs={"seed": k, "options": {"env_index": env_index}},
    )
    return episode, recorded


def write_collection(cfg: Config, root: Path) -> None:
    info = {"env_id": "aed_tasks:AED-PickPlace-base", "env_kwargs": {}, "max_episode_steps": 250}
    rng = np.random.default_rng(0)
    for start in range(0, cfg.episodes, cfg.shard_size):
        env_index, count = start // cfg.shard_size, min(cfg.shard_size, cfg.episodes - start)
        stem = f"agent_success_env{env_index:03d}_0000"
        writer = trajectory.ShardWriter(root / f"{stem}.h5", trajectory.Compression("lzf"))
        for k in range(count):
            writer.add(*synthetic_episode(rng, env_index, k, cfg.steps, cfg.frame_kib))
        writer.commit(info, {"env_index": env_index, "start": 0, "count": count})


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def first_quick(root: Path) -> None:
    trajectory._VERIFIED.clear()  # as in a new process
    trajectory.scan_collection(root, "quick")


def measure(root: Path, runs: int) -> dict[str, list[float]]:
    scans: dict[str, Callable[[], object]] = {
        "size": lambda: trajectory.scan_collection(root, "size"),
        "quick_first": lambda: first_quick(root),
        "quick_again": lambda: trajectory.scan_collection(root, "quick"),
        "full": lambda: trajectory.scan_collection(root, "full"),
    }
    trajectory.scan_collection(root, "full")  # warm the page cache once, untimed
    seconds: dict[str, list[float]] = {name: [] for name in scans}
    for run in range(runs):
        order = list(scans) if run % 2 == 0 else list(reversed(scans))
        for name in order:
            seconds[name].append(timed(scans[name]))
        logger.info("run %d: %s", run + 1, {k: round(v[-1], 3) for k, v in seconds.items()})
    return seconds


def main(cfg: Config) -> dict:
    setup_logging()
    scratch = None
    root = cfg.collection
    if root is None:
        scratch = Path(tempfile.mkdtemp(prefix="bench_shard_check_", dir=cfg.scratch))
        root = scratch / "collection"
        root.mkdir()
        logger.info("writing %d synthetic episodes into %s", cfg.episodes, root)
        write_collection(cfg, root)
    try:
        collection = trajectory.scan_collection(root, "size")
        episodes = collection.episodes()
        h5_bytes = sum(s.h5_path.stat().st_size for s in collection.shards)
        seconds = measure(root, cfg.runs)
    finally:
        if scratch is not None:
            shutil.rmtree(scratch)
    medians = {name: statistics.median(v) for name, v in seconds.items()}
    result = {
        "config": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(cfg).items()},
        "synthetic": cfg.collection is None,
        "machine": platform.platform(),
        "shards": len(collection.shards),
        "episodes": len(episodes),
        "frames": sum(e.num_frames for e in episodes),
        "h5_bytes": h5_bytes,
        "seconds": seconds,
        "median_s": medians,
        "sha256_mb_per_s": h5_bytes / 1e6 / medians["full"],
    }
    cfg.out.parent.mkdir(parents=True, exist_ok=True)
    cfg.out.write_text(json.dumps(result, indent=2))
    print(table(result))
    return result


def table(result: dict) -> str:
    m = result["median_s"]
    return "\n".join(
        [
            f"{result['episodes']} episodes, {result['shards']} shards, "
            f"{result['h5_bytes'] / 2**20:.0f} MiB "
            f"({'synthetic' if result['synthetic'] else 'collected'})",
            "| scan | median s |",
            "|---|---:|",
            *(f"| {name} | {m[name]:.3f} |" for name in m),
            f"sha256: {result['sha256_mb_per_s']:.0f} MB/s",
        ]
    )


if __name__ == "__main__":
    main(tyro.cli(Config))

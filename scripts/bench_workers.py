"""Rollout throughput with several worker processes: each worker's share of the cores against
every library's default thread pool (torch and lavapipe each size theirs to every core).

Runs the same rollouts (`aed rollout`'s runner, an untrained mini DCT policy, fresh output
folders) alternately with `AED_WORKER_THREADS` unset (the share: cores / workers) and `0`
(the libraries' defaults), `repeats` times each, and prints the median wall time of each and
their ratio. Needs a novel collection with demonstrations (`aed collect --split novel`).

    python scripts/bench_workers.py --demos runs/demo/PressButton/data/novel --envs 0 1 2 3
"""

from __future__ import annotations

import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import tyro

from aed_eval.logs import setup_logging

logger = logging.getLogger("bench_workers")


@dataclass
class Config:
    demos: Path = Path("runs/demo/PressButton/data/novel")
    """Collection with the environments' demonstrations."""
    task: str = "PressButton"
    envs: tuple[int, ...] = (0, 1, 2, 3)
    """One rollout in each (one shard each)."""
    horizon: int = 80
    workers: int = 2
    repeats: int = 3
    out: Path = Path("runs/bench_workers.json")


def run_once(cfg: Config, checkpoint: Path, threads: str | None) -> float:
    env = {k: v for k, v in os.environ.items() if k != "AED_WORKER_THREADS"}
    if threads is not None:
        env["AED_WORKER_THREADS"] = threads
    with tempfile.TemporaryDirectory() as out:
        args = [
            str(Path(sys.executable).with_name("aed")),
            "rollout",
            "--task",
            cfg.task,
            "--policy",
            "dct",
            "--checkpoint",
            str(checkpoint),
            "--demos",
            str(cfg.demos),
            "--out",
            out,
            "--envs",
            *map(str, cfg.envs),
            "--num-episodes",
            "1",
            "--shard-size",
            "1",
            "--horizon",
            str(cfg.horizon),
            "--num-demos",
            "1",
            "--workers",
            str(cfg.workers),
            "--no-progress",
        ]
        start = time.perf_counter()
        subprocess.run(args, check=True, env=env, capture_output=True)
        return time.perf_counter() - start


def main(cfg: Config) -> dict:
    from aed_models.policies import POLICIES, make_policy, save_policy

    with tempfile.TemporaryDirectory() as tmp:
        checkpoint = Path(tmp) / "policy.pt"
        save_policy(checkpoint, make_policy("dct", POLICIES.preset("dct", "mini")))
        times: dict[str, list[float]] = {"share": [], "defaults": []}
        for _ in range(cfg.repeats):
            times["share"].append(run_once(cfg, checkpoint, None))
            times["defaults"].append(run_once(cfg, checkpoint, "0"))
    medians = {k: statistics.median(v) for k, v in times.items()}
    result = {
        "config": {k: str(v) if isinstance(v, Path) else v for k, v in vars(cfg).items()},
        "cpus": os.cpu_count(),
        "seconds": times,
        "median_seconds": medians,
        "speedup": medians["defaults"] / medians["share"],
    }
    cfg.out.parent.mkdir(parents=True, exist_ok=True)
    cfg.out.write_text(json.dumps(result, indent=1))
    print(
        f"{len(cfg.envs)} rollouts x {cfg.horizon} steps on {cfg.workers} workers, "
        f"{os.cpu_count()} cores: median {medians['share']:.1f} s with each worker's "
        f"share of the cores, {medians['defaults']:.1f} s with the libraries' defaults "
        f"({result['speedup']:.2f}x)"
    )
    return result


if __name__ == "__main__":
    setup_logging()
    main(tyro.cli(Config))

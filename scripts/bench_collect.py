"""Collection overhead: `aed collect`'s recorded steps/s against raw env stepping, same run.

Each run records one shard per role (planning with mplib, recording obs and env states,
compressing, writing atomically) and then steps the same env through the very same
episodes (same seeds, environments and actions) with nothing recorded. Overhead =
collect time / raw time - 1, per run; the median over runs is reported, with the median
rates and the disk bytes per stored frame. Writes JSON and a Markdown table.

    python scripts/bench_collect.py                    # PickPlace base, 3 runs
    python scripts/bench_collect.py --runs 5 --compression lzf
"""

from __future__ import annotations

import json
import logging
import platform
import statistics
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import h5py
import tyro

from aed_eval.collect import CollectConfig, ExpertRunner, Shard
from aed_eval.logs import setup_logging

logger = logging.getLogger("bench_collect")


@dataclass
class Config:
    task: str = "PickPlace"
    split: str = "base"
    runs: int = 3
    """Timed runs; medians are reported."""
    episodes: int = 1
    """Episodes per role per run."""
    roles: tuple[str, ...] = ("agent_success", "agent_failure")
    compression: Literal["gzip", "lzf"] = "gzip"
    compression_level: int = 4
    out: Path = Path("runs/bench")


@dataclass
class Run:
    env_index: int
    steps: int
    frames: int
    collect_s: float
    raw_s: float
    disk_bytes: int

    @property
    def overhead(self) -> float:
        return self.collect_s / self.raw_s - 1.0


def raw_replay(env, h5_path: Path) -> float:
    """Seconds to reset and step `env` through every episode of a shard, recording nothing."""
    body = json.loads(h5_path.with_suffix(".json").read_text())
    with h5py.File(h5_path, "r") as f:
        actions = [f[f"traj_{e['episode_id']}/actions"][()] for e in body["episodes"]]
    start = time.perf_counter()
    for episode, acts in zip(body["episodes"], actions, strict=True):
        env.reset(**episode["reset_kwargs"])
        for action in acts:
            env.step(action)
    return time.perf_counter() - start


def bench(cfg: Config) -> dict:
    collect_cfg = CollectConfig.from_preset(
        task=cfg.task,
        split=cfg.split,
        envs=(0,),
        num_demos=0,
        num_successes=0,
        num_failures=0,
        compression=cfg.compression,
        compression_level=cfg.compression_level,
        progress=False,
    )
    runner = ExpertRunner(collect_cfg)
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(cfg.runs + 1):  # run 0 warms up (gym.make, first planner, caches)
            env_index = r
            steps = frames = size = 0
            collect_s = raw_s = 0.0
            for role in cfg.roles:
                shard = Shard(collect_cfg.task, collect_cfg.split, env_index, role, 0, cfg.episodes)
                result = runner.run(shard, out=Path(tmp))
                h5_path = Path(tmp) / f"{shard.stem}.h5"
                collect_s += result.seconds
                raw_s += raw_replay(runner.env_for(shard.demonstrator).env, h5_path)
                steps += result.steps
                frames += result.steps + result.episodes
                size += h5_path.stat().st_size + h5_path.with_suffix(".json").stat().st_size
            if r == 0:
                continue
            run = Run(env_index, steps, frames, collect_s, raw_s, size)
            logger.info(
                "run %d: %d steps, collect %.1f s, raw %.1f s, overhead %.1f%%",
                r,
                steps,
                collect_s,
                raw_s,
                100 * run.overhead,
            )
            runs.append(run)
    runner.close()
    return {
        "config": {
            k: (list(v) if isinstance(v, tuple) else str(v) if isinstance(v, Path) else v)
            for k, v in asdict(cfg).items()
        },
        "machine": {
            "python": platform.python_version(),
            "cpu": platform.processor() or platform.machine(),
        },
        "runs": [{**asdict(run), "overhead": run.overhead} for run in runs],
        "collect_steps_per_s": statistics.median(r.steps / r.collect_s for r in runs),
        "raw_steps_per_s": statistics.median(r.steps / r.raw_s for r in runs),
        "overhead": statistics.median(r.overhead for r in runs),
        "bytes_per_frame": sum(r.disk_bytes for r in runs) / sum(r.frames for r in runs),
    }


def markdown(result: dict) -> str:
    c = result["config"]
    lines = [
        (
            f"# Collection overhead ({c['task']}-{c['split']}, {c['compression']}, "
            f"{len(result['runs'])} runs)"
        ),
        "",
        "| run | env | steps | collect (s) | raw (s) | collect steps/s | raw steps/s | overhead |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(result["runs"], 1):
        lines.append(
            f"| {i} | {r['env_index']} | {r['steps']} | {r['collect_s']:.1f} | {r['raw_s']:.1f} | "
            f"{r['steps'] / r['collect_s']:.1f} | {r['steps'] / r['raw_s']:.1f} | "
            f"{100 * r['overhead']:.1f}% |"
        )
    lines += [
        "",
        (
            f"- median collect rate: {result['collect_steps_per_s']:.1f} steps/s; raw env: "
            f"{result['raw_steps_per_s']:.1f} steps/s"
        ),
        (
            "- median overhead (planning + recording + compression + atomic write): "
            f"**{100 * result['overhead']:.1f}%** (target <= 30%)"
        ),
        (
            f"- disk: {result['bytes_per_frame'] / 1024:.1f} KiB per stored frame "
            "(RGB-D 160x120, obs + env states)"
        ),
    ]
    return "\n".join(lines) + "\n"


def main(cfg: Config) -> None:
    setup_logging()
    result = bench(cfg)
    cfg.out.mkdir(parents=True, exist_ok=True)
    stem = cfg.out / f"collect_{cfg.task}_{cfg.compression}"
    stem.with_suffix(".json").write_text(json.dumps(result, indent=2))
    stem.with_suffix(".md").write_text(markdown(result))
    print(markdown(result))


if __name__ == "__main__":
    main(tyro.cli(Config))

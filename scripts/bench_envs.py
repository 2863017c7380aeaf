"""Benchmark the AED envs against ManiSkill's PickCube-v1, measured in the same run.

For every AED env and for PickCube-v1 with the same 160x120 RGB-D camera: steps/s (median
of several runs), reset and reconfiguring-reset times, and one rendered expert episode.
PickCube is measured before and after the AED envs, so drift of a shared, noisy machine
shows up instead of skewing the ratio. Writes JSON and a Markdown table.

    python scripts/bench_envs.py                       # every task, base split
    python scripts/bench_envs.py --tasks PickPlace --runs 3 --steps 20
"""

from __future__ import annotations

import json
import logging
import platform
import statistics
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (registers PickCube-v1)
import numpy as np
import tyro

import aed_tasks
from aed_eval.logs import setup_logging
from aed_tasks import solve

logger = logging.getLogger("bench_envs")


@dataclass
class Config:
    tasks: tuple[str, ...] = ()
    """Tasks to measure (default: every registered task)."""
    split: str = "base"
    runs: int = 5
    """Timed runs per env; the median is reported."""
    steps: int = 30
    """Steps per timed run."""
    reconfigures: int = 5
    out: Path = Path("runs/bench")


def time_steps(env: gym.Env, runs: int, steps: int, seed: int = 0) -> list[float]:
    """Steps/s of `runs` runs of `steps` random actions (after a short warm-up)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    for _ in range(3):
        env.step(rng.uniform(-1, 1, 4).astype(np.float32))
    rates = []
    for _ in range(runs):
        env.reset(seed=seed)
        actions = rng.uniform(-0.3, 0.3, (steps, 4)).astype(np.float32)
        start = time.perf_counter()
        for action in actions:
            env.step(action)
        rates.append(steps / (time.perf_counter() - start))
    return rates


def time_resets(env: gym.Env, n: int) -> tuple[float, float]:
    """Median seconds of a plain reset (no seed) and of a reconfiguring reset (a seed: a new
    environment of the catalogue, built from scratch)."""
    plain, reconfigure = [], []
    for k in range(n):
        start = time.perf_counter()
        env.reset(seed=k, options={"reconfigure": True})
        reconfigure.append(time.perf_counter() - start)
        start = time.perf_counter()
        env.reset()
        plain.append(time.perf_counter() - start)
    return statistics.median(plain), statistics.median(reconfigure)


@dataclass
class Row:
    env_id: str
    steps_per_s: float
    ratio_to_pickcube: float
    reset_s: float
    reconfigure_s: float
    expert_episode_s: float
    expert_steps: int


def bench_pickcube(cfg: Config) -> list[float]:
    env = gym.make(
        "PickCube-v1",
        obs_mode="rgbd",
        control_mode="pd_ee_delta_pos",
        sensor_configs={"width": 160, "height": 120},
    )
    rates = time_steps(env, cfg.runs, cfg.steps)
    env.close()
    return rates


def main(cfg: Config) -> None:
    setup_logging()
    tasks = cfg.tasks or tuple(sorted(aed_tasks.TASKS))
    reference = bench_pickcube(cfg)
    logger.info("PickCube-v1 (before): %.1f steps/s", statistics.median(reference))
    measured = []
    for task in tasks:
        env_id = aed_tasks.env_id(task, cfg.split)
        env = gym.make(env_id)
        rates = time_steps(env, cfg.runs, cfg.steps)
        reset_s, reconfigure_s = time_resets(env, cfg.reconfigures)
        start = time.perf_counter()
        episode = solve(env, seed=0)
        expert_s = time.perf_counter() - start
        env.close()
        measured.append((env_id, rates, reset_s, reconfigure_s, expert_s, len(episode)))
        logger.info(
            "%s: %.1f steps/s, reconfigure %.2f s", env_id, statistics.median(rates), reconfigure_s
        )
    after = bench_pickcube(cfg)
    logger.info("PickCube-v1 (after): %.1f steps/s", statistics.median(after))
    reference_rate = statistics.median(reference + after)

    rows = [Row("PickCube-v1", reference_rate, 1.0, float("nan"), float("nan"), float("nan"), 0)]
    for env_id, rates, reset_s, reconfigure_s, expert_s, steps in measured:
        rate = statistics.median(rates)
        rows.append(
            Row(env_id, rate, rate / reference_rate, reset_s, reconfigure_s, expert_s, steps)
        )

    cfg.out.mkdir(parents=True, exist_ok=True)
    meta = {
        "machine": platform.node(),
        "python": platform.python_version(),
        "config": {k: str(v) for k, v in asdict(cfg).items()},
    }
    (cfg.out / "bench_envs.json").write_text(
        json.dumps(
            {"meta": meta, "pickcube_runs": reference + after, "rows": [asdict(r) for r in rows]},
            indent=2,
        )
    )
    lines = [
        (
            "| env | steps/s (median) | x PickCube-v1 | reset s | reconfigure s | "
            "expert episode s (steps) |"
        ),
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        expert = "" if r.expert_steps == 0 else f"{r.expert_episode_s:.1f} ({r.expert_steps})"
        reset = "" if np.isnan(r.reset_s) else f"{r.reset_s:.3f}"
        reconf = "" if np.isnan(r.reconfigure_s) else f"{r.reconfigure_s:.2f}"
        lines.append(
            f"| {r.env_id} | {r.steps_per_s:.1f} | {r.ratio_to_pickcube:.2f} | {reset} | "
            f"{reconf} | {expert} |"
        )
    table = "\n".join(lines)
    (cfg.out / "bench_envs.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main(tyro.cli(Config))

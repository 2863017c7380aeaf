"""Expert success and error-injection rates of tasks, over seeds spread across splits.

Clean episodes alternate base / novel environments and spread over each catalogue; each
error kind runs the same way. Physics only (obs_mode="state"): rendering changes nothing
about success. Writes JSON and prints a Markdown table.

    python scripts/expert_stats.py --tasks PickPlace --seeds 40 --error-seeds 20
    python scripts/expert_stats.py --workers 2          # every task, two processes
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import tyro

import aed_tasks
from aed_eval.logs import setup_logging
from aed_tasks import ErrorSpec, solve

logger = logging.getLogger("expert_stats")


@dataclass
class Config:
    tasks: tuple[str, ...] = ()
    """Tasks to measure (default: every registered task)."""
    seeds: int = 40
    """Clean expert episodes per task (half base, half novel)."""
    error_seeds: int = 20
    """Episodes per error kind."""
    out: Path = Path("runs/expert_stats")
    first_seed: int = 1000
    workers: int = 1
    """Tasks measured in parallel processes."""


def spread(n: int, size: int) -> list[int]:
    """n environment indices spread evenly over a catalogue of `size`."""
    return [int(k * size / max(n, 1)) % size for k in range(n)]


def measure(task: str, kind: str | None, n: int, first_seed: int, envs: dict) -> dict:
    outcomes, onsets_ok, lengths, failures = [], [], [], []
    per_split = {"base": spread((n + 1) // 2, len(envs["base"].unwrapped.catalogue)),
                 "novel": spread(n // 2, len(envs["novel"].unwrapped.catalogue))}  # fmt: skip
    start = time.perf_counter()
    for split, indices in per_split.items():
        for k, env_index in enumerate(indices):
            seed = first_seed + 2 * k + (split == "novel")
            ep = solve(envs[split], seed, ErrorSpec(kind) if kind else None, env_index=env_index)
            outcomes.append(ep.succeeded)
            lengths.append(len(ep))
            if kind is not None:
                onset = ep.error_onset
                onsets_ok.append(onset is not None and not ep.error_label[:onset].any() and ep.error_label[onset:].all())
            elif not ep.succeeded:
                failures.append((split, env_index, seed))
    rate = float(np.mean(outcomes))
    return {
        "kind": kind or "clean", "episodes": len(outcomes),
        "success_rate": rate, "target": "success" if kind is None else "failure",
        "labels_switch_at_onset": float(np.mean(onsets_ok)) if onsets_ok else None,
        "mean_length": float(np.mean(lengths)) if lengths else 0.0,
        "seconds_per_episode": (time.perf_counter() - start) / max(len(outcomes), 1),
        "unsuccessful_clean": failures if kind is None else [],
    }  # fmt: skip


def measure_task(task: str, cfg: Config) -> list[dict]:
    """Clean and every error kind of one task; writes `<out>/<task>.json`."""
    setup_logging()
    cls = aed_tasks.get_task(task)
    envs = {s: gym.make(aed_tasks.env_id(task, s), obs_mode="state") for s in ("base", "novel")}
    results = [measure(task, None, cfg.seeds, cfg.first_seed, envs)]
    results += [measure(task, kind, cfg.error_seeds, cfg.first_seed, envs) for kind in cls.error_kinds]
    for env in envs.values():
        env.close()
    (cfg.out / f"{task}.json").write_text(json.dumps({"task": task, "results": results}, indent=2))
    logger.info("%s done", task)
    return results


def main(cfg: Config) -> None:
    setup_logging()
    tasks = cfg.tasks or tuple(sorted(aed_tasks.TASKS))
    cfg.out.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(cfg.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        per_task = list(pool.map(measure_task, tasks, [cfg] * len(tasks)))
    rows = []
    for task, results in zip(tasks, per_task, strict=True):
        for r in results:
            rate = r["success_rate"] if r["kind"] == "clean" else 1 - r["success_rate"]
            labels = "" if r["labels_switch_at_onset"] is None else f"{r['labels_switch_at_onset']:.0%}"
            rows.append(f"| {task} | {r['kind']} | {r['episodes']} | {rate:.0%} | {labels} | {r['mean_length']:.0f} | {r['seconds_per_episode']:.1f} |")
    table = "| task | episodes of | n | expert success (clean) / failure (error) | labels at onset | mean steps | s/episode |\n"
    table += "|---|---|---|---|---|---|---|\n" + "\n".join(rows)
    (cfg.out / "expert_stats.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main(tyro.cli(Config))

"""Expert success and error-injection rates of tasks, over seeds spread across splits.

Clean episodes alternate base / novel environments and spread over each catalogue; each
error kind runs the same way. Per error kind: how often the episode failed, failed in its
named way (the task's `error_outcome`, not cut by the time limit), and departed from its clean
twin (same seed and environment) exactly at the labelled onset (`aed_tasks.expert.departure`).
Physics only (obs_mode="state"): rendering changes nothing about success. Writes JSON and
prints a Markdown table.

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
from aed_tasks import ErrorSpec
from aed_tasks.expert import departure, trace_episode

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
    resume: bool = True
    """Reuse `<out>/<task>.json` of a task measured with the same seeds (a killed run goes on)."""


def spread(n: int, size: int) -> list[int]:
    """n environment indices spread evenly over a catalogue of `size`."""
    return [int(k * size / max(n, 1)) % size for k in range(n)]


def episodes(n: int, envs: dict, first_seed: int) -> list[tuple[str, int, int]]:
    """(split, seed, env index) of n episodes: half base, half novel, spread over each catalogue."""
    per_split = {
        "base": spread((n + 1) // 2, len(envs["base"].unwrapped.catalogue)),
        "novel": spread(n // 2, len(envs["novel"].unwrapped.catalogue)),
    }
    return [
        (split, first_seed + 2 * k + (split == "novel"), index)
        for split, indices in per_split.items()
        for k, index in enumerate(indices)
    ]


def measure(kind: str | None, runs: list[tuple[str, int, int]], envs: dict, clean: dict) -> dict:
    """Clean (kind None) or one error kind over `runs`. Error episodes are checked for their
    named outcome and against their clean twin (same seed and environment, from `clean`, a cache
    of clean traces filled on demand) for the departure at the onset."""
    outcomes, named, departs, lengths, failures, problems = [], [], [], [], [], []
    truncated = 0
    start = time.perf_counter()
    for split, seed, env_index in runs:
        ep, trace = trace_episode(envs[split], seed, ErrorSpec(kind) if kind else None, env_index)
        outcomes.append(ep.succeeded)
        lengths.append(len(ep))
        truncated += ep.truncated
        if kind is None:
            clean[(split, seed, env_index)] = trace
            if not ep.succeeded:
                failures.append((split, env_index, seed))
            continue
        named.append(not ep.outcome_problem and not ep.truncated)
        if (split, seed, env_index) not in clean:
            clean[(split, seed, env_index)] = trace_episode(envs[split], seed, None, env_index)[1]
        problem = departure(clean[(split, seed, env_index)], trace, ep.error_onset).problem
        departs.append(not problem)
        for what in filter(None, (ep.outcome_problem, problem)):
            problems.append(f"{split} env {env_index} seed {seed}: {what}")
    return {
        "kind": kind or "clean",
        "episodes": len(outcomes),
        "success_rate": float(np.mean(outcomes)) if outcomes else float("nan"),
        "target": "success" if kind is None else "failure",
        "named_failure_rate": float(np.mean(named)) if named else None,
        "departure_rate": float(np.mean(departs)) if departs else None,
        "truncated": int(truncated),
        "mean_length": float(np.mean(lengths)) if lengths else 0.0,
        "min_length": int(np.min(lengths)) if lengths else 0,
        "max_length": int(np.max(lengths)) if lengths else 0,
        "seconds_per_episode": (time.perf_counter() - start) / max(len(outcomes), 1),
        "unsuccessful_clean": failures,
        "problems": problems,
    }


def measure_task(task: str, cfg: Config) -> list[dict]:
    """Clean and every error kind of one task; writes `<out>/<task>.json`."""
    setup_logging()
    path, seeds = cfg.out / f"{task}.json", [cfg.seeds, cfg.error_seeds, cfg.first_seed]
    if cfg.resume and path.exists():
        stored = json.loads(path.read_text())
        if stored.get("seeds") == seeds:
            logger.info("%s: reusing %s", task, path)
            return stored["results"]
    cls = aed_tasks.get_task(task)
    envs = {s: gym.make(aed_tasks.env_id(task, s), obs_mode="state") for s in ("base", "novel")}
    clean: dict = {}
    results = [measure(None, episodes(cfg.seeds, envs, cfg.first_seed), envs, clean)]
    error_runs = episodes(cfg.error_seeds, envs, cfg.first_seed)
    results += [measure(kind, error_runs, envs, clean) for kind in cls.error_kinds]
    for env in envs.values():
        env.close()
    path.write_text(json.dumps({"task": task, "seeds": seeds, "results": results}, indent=2))
    logger.info("%s done", task)
    return results


def percent(rate: float | None) -> str:
    return "" if rate is None else f"{rate:.0%}"


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
            rows.append(
                f"| {task} | {r['kind']} | {r['episodes']} | {rate:.0%} | "
                f"{percent(r['named_failure_rate'])} | {percent(r['departure_rate'])} | "
                f"{r['truncated']} | {r['mean_length']:.0f} | {r['seconds_per_episode']:.1f} |"
            )
    table = (
        "| task | episodes of | n | expert success (clean) / failure (error) | failed as named "
        "| departs at the onset | cut by the time limit | mean steps | s/episode |\n"
    )
    table += "|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows)
    (cfg.out / "expert_stats.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main(tyro.cli(Config))

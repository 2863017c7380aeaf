"""`aed demo`: the whole pipeline on a small default, end to end on a CPU machine.

What exists of the protocol runs here, in order (later stages join as they land):

1. the benchmark: every task's base and novel environments rendered, and its expert run
   clean and with every behaviour error in a novel environment;
2. phase-1/2 data: a small `aed collect` of one task's base split (demonstrations, agent
   successes, agent failures of every kind), summarised as `aed data-info` does;
3. training batches: one iteration of the detectors' composition drawn from it, with
   rollout augmentation, checked for aligned labels.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

logger = logging.getLogger(__name__)


def demo(
    out: Path = Path("runs/demo"),
    tasks: tuple[str, ...] = (),
    seed: int = 0,
    collect_task: str = "PickPlace",
    collect_envs: int = 2,
    workers: int = 1,
) -> int:
    """Render every task, run its expert clean and with every error, collect a small base-split
    dataset of one task, and draw a training batch from it; results land under `out`.

    Args:
        out: output folder.
        tasks: task names of the benchmark step (default: every registered task).
        seed: episode seed of the benchmark step; root seed of the collection.
        collect_task: the task whose base split is collected.
        collect_envs: environments collected (2 demonstrations, 2 successes, 3 failures each).
        workers: collection processes.
    """
    from aed_eval.doctor import rendering_device

    if rendering_device() is None:
        logger.error("SAPIEN finds no rendering device: run `aed doctor`")
        return 1
    experts = run_experts(out, tasks, seed)
    data = collect_data(out / "data" / collect_task, collect_task, collect_envs, seed, workers)
    batch = draw_batch(out / "data" / collect_task, seed)
    summary = {"experts": experts, "data": data, "batch": batch}
    (out / "demo.json").write_text(json.dumps(summary, indent=2, default=str))
    ok = all(r["success"] == (r["error"] == "none") for r in experts) and batch["labels_aligned"]
    logger.info("demo %s: results under %s", "finished" if ok else "FAILED", out)
    return 0 if ok else 1


def run_experts(out: Path, tasks: tuple[str, ...], seed: int) -> list[dict[str, Any]]:
    """Images of every task, then its expert clean and with each error (novel env 0)."""
    import gymnasium as gym

    import aed_tasks
    from aed_eval.render import render_envs

    tasks = tasks or tuple(aed_tasks.TASKS)
    images = render_envs(tasks=tasks, out=out / "images", seed=seed, large=False)
    logger.info("wrote %d images under %s", len(images), out / "images")
    rows = []
    for task in tasks:
        env = gym.make(aed_tasks.env_id(task, "novel"), obs_mode="state")
        for kind in (None, *aed_tasks.get_task(task).error_kinds):
            start = time.perf_counter()
            episode = aed_tasks.solve(env, seed, aed_tasks.ErrorSpec(kind) if kind else None, env_index=0)
            rows.append({
                "task": task, "error": kind or "none", "steps": len(episode), "success": episode.succeeded,
                "onset": episode.error_onset, "seconds": round(time.perf_counter() - start, 2),
            })  # fmt: skip
            logger.info("%s", rows[-1])
        env.close()
    out.mkdir(parents=True, exist_ok=True)
    table = ["| task | injected error | steps | success | onset |", "|---|---|---|---|---|"]
    table += [f"| {r['task']} | {r['error']} | {r['steps']} | {r['success']} | {r['onset']} |" for r in rows]
    (out / "experts.md").write_text("\n".join(table) + "\n")
    print("\n".join(table))
    return rows


def collect_data(out: Path, task: str, num_envs: int, seed: int, workers: int) -> dict[str, Any]:
    """A small base-split collection (resumes if `out` holds part of it)."""
    import aed_tasks
    from aed_eval.collect import CollectConfig, run_collection
    from aed_eval.data_info import format_summary, summarize

    kinds = len(aed_tasks.get_task(task).error_kinds)
    cfg = CollectConfig(
        task=task, split="base", out=out, num_envs=num_envs, num_demos=2, num_successes=2,
        num_failures=kinds, seed=seed, workers=workers,
    )  # fmt: skip
    run_collection(cfg)
    info = summarize(out)
    print(format_summary(info))
    return info


def draw_batch(root: Path, seed: int) -> dict[str, Any]:
    """One detector training iteration (5 demos + 10 successes + 10 failures), augmented."""
    from aed_models.augment import RolloutAugment
    from aed_models.data import EnvironmentIterations, load_episodes

    data = EnvironmentIterations(load_episodes(root), "detector", augment=RolloutAugment(), max_frames=64, seed=seed)
    batch = data[0]
    rollouts = batch["rollouts"]
    aligned = all(
        plausible_labels(rollouts["labels"][i, :n], bool(rollouts["is_failure"][i]))
        for i, n in enumerate(rollouts["lengths"].tolist())
    )
    shapes = {k: list(v["frames"].shape) for k, v in (("demos", batch["demos"]), ("rollouts", rollouts))}
    logger.info("training batch of environment %d: %s, labels aligned: %s", batch["env_index"], shapes, aligned)
    return {"env_index": batch["env_index"], "shapes": shapes, "labels_aligned": bool(aligned)}


def plausible_labels(labels: Any, failure: bool) -> bool:
    """A success is normal throughout; a failure starts normal and turns to error.

    (Augmentation may swap two frames at the onset; exact alignment is checked by the tests.)
    """
    return bool(labels[0] == 0 and labels.any()) if failure else not bool(labels.any())

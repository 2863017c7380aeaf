"""`aed demo`: the whole pipeline on a small default, end to end on a CPU machine.

What exists of the protocol runs here, in order; later stages join as they land.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

logger = logging.getLogger(__name__)


def demo(out: Path = Path("runs/demo"), tasks: tuple[str, ...] = (), seed: int = 0) -> int:
    """Render every task's base and novel environments, then run its expert clean and with
    every behaviour error, and write a summary (JSON + Markdown) under `out`.

    Args:
        out: output folder.
        tasks: task names (default: every registered task).
        seed: episode seed.
    """
    import gymnasium as gym

    import aed_tasks
    from aed_eval.doctor import rendering_device
    from aed_eval.render import render_envs

    if rendering_device() is None:
        logger.error("SAPIEN finds no rendering device: run `aed doctor`")
        return 1
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
    (out / "experts.json").write_text(json.dumps(rows, indent=2))
    table = ["| task | injected error | steps | success | onset |", "|---|---|---|---|---|"]
    table += [f"| {r['task']} | {r['error']} | {r['steps']} | {r['success']} | {r['onset']} |" for r in rows]
    (out / "experts.md").write_text("\n".join(table) + "\n")
    print("\n".join(table))
    expected = all(r["success"] == (r["error"] == "none") for r in rows)
    logger.info("demo finished: results under %s", out)
    return 0 if expected else 1

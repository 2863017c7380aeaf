"""`aed render`: images of base and novel environments, to look at the benchmark."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)


def _save_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")


def render_envs(
    tasks: tuple[str, ...] = (),
    env_indices: tuple[int, ...] = (0,),
    out: Path = Path("runs/images"),
    seed: int = 0,
    large: bool = True,
) -> list[Path]:
    """Render the `front` camera (160x120, and a 640x480 view when `large`) of chosen
    environments of every task's base and novel split, plus a base|novel contact sheet.

    Args:
        tasks: task names (default: all registered).
        env_indices: environments of each split's catalogue to render.
        out: output folder.
        seed: episode seed (object poses).
        large: also save the 640x480 human-render camera.
    """
    import gymnasium as gym

    import aed_tasks

    written: list[Path] = []
    for task in tasks or tuple(aed_tasks.TASKS):
        aed_tasks.get_task(task)  # a clear error for an unknown name
        sheet = []
        for split in ("base", "novel"):
            env = gym.make(aed_tasks.env_id(task, split), render_mode="rgb_array")
            row = []
            for index in env_indices:
                obs, _ = env.reset(seed=seed, options={"env_index": index})
                front = obs["sensor_data"]["front"]["rgb"][0].numpy()
                stem = out / f"{task}_{split}_{index}"
                _save_png(stem.with_suffix(".png"), front)
                written.append(stem.with_suffix(".png"))
                if large:
                    view = np.asarray(env.render()[0])
                    _save_png(stem.with_name(stem.name + "_large.png"), view)
                    written.append(stem.with_name(stem.name + "_large.png"))
                row.append(front)
            sheet.append(np.concatenate(row, axis=1))
            env.close()
        sheet_path = out / f"{task}_base_vs_novel.png"
        _save_png(sheet_path, np.concatenate(sheet, axis=0))
        written.append(sheet_path)
        logger.info("rendered %s -> %s", task, sheet_path)
    return written

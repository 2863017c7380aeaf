"""Helpers shared by test modules."""

from __future__ import annotations

import importlib.util
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np


def load_script(name: str) -> ModuleType:
    """A module of scripts/ (not a package), imported by path."""
    path = Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def recorded_episode(
    task: str,
    role: str,
    env_index: int,
    seed: int,
    rgb: np.ndarray,
    depth: np.ndarray,
    actions: np.ndarray,
    tcp_pose: np.ndarray,
    env_states: dict | None = None,
    onset: int | None = None,
    split: str = "base",
    sensor_param: dict | None = None,
    stage: np.ndarray | None = None,
) -> tuple[Any, Any]:
    """A synthetic episode as the collector records it: (T + 1) frames and TCP poses, T
    actions, success at the last step, or (`onset` given) a `no_grasp` failure from `onset`
    (role `explore`: an exploration episode); `sensor_param` the front camera's (T + 1)
    intrinsic_cv / extrinsic_cv; `stage` the per-step stages completed (default none)."""
    from aed_tasks import trajectory
    from aed_tasks.episode import Episode

    steps = len(actions)
    labels = np.zeros(steps, np.uint8)
    if onset is not None:
        labels[onset:] = 1
    episode = Episode(
        env_id=f"AED-{task}-{split}",
        task=task,
        split=split,
        env_index=env_index,
        seed=seed,
        demonstrator=role == "demo",
        control_mode="pd_ee_delta_pos",
        actions=actions.astype(np.float32),
        success=(np.arange(steps) == steps - 1) & (onset is None),
        fail=np.zeros(steps, bool),
        stage=np.zeros(steps, np.int16) if stage is None else np.asarray(stage, np.int16),
        error_label=labels,
        error_kind=None if onset is None else "no_grasp",
        error_onset=onset,
        explore=role == "explore",
    )
    recorded = trajectory.RecordedSteps(
        obs={
            "sensor_data": {"front": {"rgb": rgb, "depth": depth}},
            "extra": {"tcp_pose": tcp_pose.astype(np.float32)},
            "agent": {"qpos": np.tile(np.float32([0.0] * 7 + [0.04, 0.04]), (steps + 1, 1))},
            **({"sensor_param": {"front": sensor_param}} if sensor_param else {}),
        },
        env_states=env_states,
        terminated=np.zeros(steps, bool),
        truncated=np.zeros(steps, bool),
        rewards=np.zeros(steps, np.float32),
        reset_kwargs={"seed": seed, "options": {"env_index": env_index}},
    )
    return episode, recorded


def write_synthetic_collection(
    root: Path,
    counts: dict[str, int],
    envs: tuple[int, ...] = (0, 1),
    steps: int = 12,
    step_increment: int = 2,
    make_episode: Callable[..., tuple[Any, Any]] | None = None,
    demo_seed_offset: int = 0,
) -> Path:
    """A collection without simulation: per environment, one shard per role with `counts[role]`
    episodes of `steps`, `steps + step_increment`, ... steps. Episode k of environment e has seed
    100 e + k (+ `demo_seed_offset` for demonstrations); `make_episode(role, env_index, seed,
    steps)` builds it (default `tests.test_data.synthetic`)."""
    from aed_tasks import trajectory

    if make_episode is None:
        from tests.test_data import synthetic as make_episode

    root.mkdir(parents=True, exist_ok=True)
    for env_index in envs:
        for role, n in counts.items():
            writer = trajectory.ShardWriter(root / f"{role}_env{env_index:03d}_0000.h5")
            for k in range(n):
                seed = 100 * env_index + demo_seed_offset * (role == "demo") + k
                episode, recorded = make_episode(
                    role, env_index, seed=seed, steps=steps + step_increment * k
                )
                writer.add(episode, recorded)
            info = {
                "env_id": f"aed_tasks:{episode.env_id}",
                "env_kwargs": {},
                "max_episode_steps": 250,
            }
            writer.commit(info, {"env_index": env_index, "group": role})
    return root


def aed(argv: list[str], caplog: Any, capsys: Any) -> tuple[int, list[str], str]:
    """`aed <argv>` run in this process through the console script's `main`: its exit status,
    the error lines it logged and its stdout. A parse, not an interpreter start (see
    tests/test_cli.py and the kill tests for the console script itself)."""
    from aed_eval import cli

    caplog.clear()
    capsys.readouterr()
    with caplog.at_level(logging.ERROR, logger="aed"):
        status = cli.main(argv)
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    return status, errors, capsys.readouterr().out

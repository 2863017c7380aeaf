"""Registering AED tasks: one class, two ids (`AED-<Task>-base`, `AED-<Task>-novel`)."""

from __future__ import annotations

from mani_skill.utils.registration import register_env

from aed_tasks.assets import SPLITS
from aed_tasks.base_env import AEDBaseEnv

TASKS: dict[str, type[AEDBaseEnv]] = {}


def env_id(task: str, split: str) -> str:
    return f"AED-{task}-{split}"


def register_task(cls: type[AEDBaseEnv]) -> type[AEDBaseEnv]:
    """Class decorator: register a task's base and novel splits with ManiSkill and Gymnasium."""
    if not cls.task_name:
        raise ValueError(f"{cls.__name__} must set task_name")
    for split in SPLITS:
        register_env(env_id(cls.task_name, split), max_episode_steps=cls.max_episode_steps, split=split)(cls)
    TASKS[cls.task_name] = cls
    return cls


def get_task(name: str) -> type[AEDBaseEnv]:
    """The task class by name (`PickPlace`) or id (`AED-PickPlace-novel`)."""
    key = name.removeprefix("AED-").rsplit("-", 1)[0] if name.startswith("AED-") else name
    if key not in TASKS:
        raise KeyError(f"unknown task {name!r}; known: {sorted(TASKS)}")
    return TASKS[key]


def registered_ids() -> list[str]:
    return [env_id(task, split) for task in TASKS for split in SPLITS]

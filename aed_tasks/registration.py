"""Registering AED tasks: one class, two ids (`AED-<Task>-base`, `AED-<Task>-novel`).

ManiSkill's `register_env` wraps every env in its `TimeLimitWrapper`, which does not record its
arguments: Gymnasium then cannot rebuild an env from its spec (`gym.make(env.spec)`, the close
and render checks of `check_env`). We register with ManiSkill's registry as `register_env`
does, and with Gymnasium using `EpisodeTimeLimit`, the same batched time limit, recreatable.
"""

from __future__ import annotations

from copy import deepcopy
from functools import partial
from typing import Any

import gymnasium as gym
import torch
from mani_skill.utils import registration as ms_registration
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper as ManiSkillCPUGymWrapper

from aed_tasks.assets import SPLITS
from aed_tasks.base_env import AEDBaseEnv

TASKS: dict[str, type[AEDBaseEnv]] = {}
PAPER_TASK_ORDER = (
    "CloseDrawer",
    "PressButton",
    "PickPlace",
    "MoveGlassCup",
    "OrganizeTable",
    "BackToBox",
    "FactoryPacking",
)  # the seven tasks in the paper's order (its tables' columns)


class EpisodeTimeLimit(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """ManiSkill's time limit (`truncated` a batched torch tensor), recreatable from `env.spec`.

    `gym.make(id, max_episode_steps=n)` puts Gymnasium's `TimeLimit` underneath: this wrapper
    takes over its limit and removes it, so that `truncated` keeps ManiSkill's type.
    """

    def __init__(self, env: gym.Env, max_episode_steps: int | None):
        if isinstance(env, gym.wrappers.TimeLimit):
            max_episode_steps = env.get_wrapper_attr("_max_episode_steps")
            env = env.env
        gym.utils.RecordConstructorArgs.__init__(self, max_episode_steps=max_episode_steps)
        gym.Wrapper.__init__(self, env)
        self._max_episode_steps = max_episode_steps

    def step(self, action: Any) -> tuple:
        obs, reward, terminated, _, info = self.env.step(action)
        base = self.env.unwrapped
        if self._max_episode_steps is None:
            truncated = torch.zeros(base.num_envs, dtype=torch.bool, device=base.device)
        else:
            truncated = base.elapsed_steps >= self._max_episode_steps
        return obs, reward, terminated, truncated, info

    @property
    def max_episode_steps(self) -> int | None:
        """The limit in force (ManiSkill's `find_max_episode_steps_value` reads it)."""
        return self._max_episode_steps


class CPUGymWrapper(ManiSkillCPUGymWrapper, gym.utils.RecordConstructorArgs):
    """ManiSkill's `CPUGymWrapper` (numpy, unbatched: the plain Gymnasium API), recreatable.

    ManiSkill's wrapper does not record its arguments either, so an env it wraps has a spec
    that `gym.make` refuses; this one behaves the same and rebuilds from `env.spec`.
    """

    def __init__(
        self, env: gym.Env, ignore_terminations: bool = False, record_metrics: bool = False
    ):
        gym.utils.RecordConstructorArgs.__init__(
            self, ignore_terminations=ignore_terminations, record_metrics=record_metrics
        )
        super().__init__(
            env, ignore_terminations=ignore_terminations, record_metrics=record_metrics
        )


def env_id(task: str, split: str) -> str:
    return f"AED-{task}-{split}"


def register_task(cls: type[AEDBaseEnv]) -> type[AEDBaseEnv]:
    """Class decorator: register a task's base and novel splits with ManiSkill and Gymnasium."""
    if not cls.task_name:
        raise ValueError(f"{cls.__name__} must set task_name")
    for split in SPLITS:
        _register(env_id(cls.task_name, split), cls, cls.max_episode_steps, {"split": split})
    TASKS[cls.task_name] = cls
    return cls


def _register(
    uid: str, cls: type[AEDBaseEnv], max_episode_steps: int, kwargs: dict[str, Any]
) -> None:
    """ManiSkill's `register_env`, with `EpisodeTimeLimit` in place of its `TimeLimitWrapper`."""
    known = ms_registration.REGISTERED_ENVS.get(uid)
    if known is not None:
        if known.cls.__qualname__ != cls.__qualname__:
            raise ValueError(f"{uid} is already registered by {known.cls.__qualname__}")
        return  # the same task again (a reloaded module): keep the first registration
    ms_registration.register(
        uid, cls, max_episode_steps=max_episode_steps, default_kwargs=deepcopy(kwargs)
    )
    gym.register(
        uid,
        entry_point=partial(ms_registration.make, env_id=uid),
        max_episode_steps=max_episode_steps,
        disable_env_checker=True,  # as ManiSkill: its observation spaces start empty
        kwargs=deepcopy(kwargs),
        additional_wrappers=(EpisodeTimeLimit.wrapper_spec(max_episode_steps=max_episode_steps),),
    )


def get_task(name: str) -> type[AEDBaseEnv]:
    """The task class by name (`PickPlace`) or id (`AED-PickPlace-novel`)."""
    key = name.removeprefix("AED-").rsplit("-", 1)[0] if name.startswith("AED-") else name
    if key not in TASKS:
        raise KeyError(f"unknown task {name!r}; known: {sorted(TASKS)}")
    return TASKS[key]


def registered_ids() -> list[str]:
    return [env_id(task, split) for task in TASKS for split in SPLITS]

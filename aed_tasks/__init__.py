"""AED benchmark: seven multi-stage manipulation tasks as ManiSkill environments.

Importing this package registers `AED-<Task>-base` and `AED-<Task>-novel` for every task,
so `gym.make("AED-PickPlace-novel")` works with no other argument.
"""

from aed_tasks import tasks  # noqa: F401  (registers every task)
from aed_tasks.base_env import AEDBaseEnv
from aed_tasks.episode import Episode
from aed_tasks.expert import ErrorSpec, ScriptedExpert, solve
from aed_tasks.registration import (
    PAPER_TASK_ORDER,
    TASKS,
    env_id,
    get_task,
    register_task,
    registered_ids,
)

__all__ = [
    "PAPER_TASK_ORDER",
    "TASKS",
    "AEDBaseEnv",
    "Episode",
    "ErrorSpec",
    "ScriptedExpert",
    "env_id",
    "get_task",
    "register_task",
    "registered_ids",
    "solve",
]

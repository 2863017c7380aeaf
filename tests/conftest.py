"""Shared fixtures: one env per registered id per session (gym.make costs seconds)."""

from __future__ import annotations

import gc
from unittest.mock import patch

import gymnasium as gym
import pytest

import aed_tasks
from aed_eval.logs import quiet_maniskill

ALL_IDS = aed_tasks.registered_ids()
ALL_TASKS = sorted(aed_tasks.TASKS)

quiet_maniskill()


@pytest.fixture(scope="module")
def make_env():
    """A factory that closes what it made at the end of the module."""
    made = []

    def _make(env_id: str, **kwargs):
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    with patch("gc.collect"):  # ManiSkill collects all garbage at each close: once is enough
        for env in made:
            env.close()
    gc.collect()

"""Every task's expert: one clean episode succeeds, every injected error fails, labels align."""

from __future__ import annotations

import numpy as np
import pytest

import aed_tasks
from aed_tasks import ErrorSpec, solve

from .conftest import ALL_TASKS

CASES = [(task, None) for task in ALL_TASKS] + [
    (task, kind) for task in ALL_TASKS for kind in aed_tasks.get_task(task).error_kinds
]


@pytest.mark.parametrize(("task", "kind"), CASES, ids=[f"{t}-{k or 'clean'}" for t, k in CASES])
def test_expert_episode(task, kind, make_env):
    env = make_env(f"AED-{task}-base", obs_mode="state")
    episode = solve(env, seed=11, error=ErrorSpec(kind) if kind else None, env_index=3)
    assert episode.env_index == 3 and len(episode) > 10
    assert episode.actions.shape == (len(episode), 4) and np.abs(episode.actions).max() <= 1
    if kind is None:
        assert episode.succeeded, f"clean {task} expert failed (stage {episode.stage.max()})"
        assert episode.error_onset is None and not episode.error_label.any()
        assert episode.stage[-1] == env.unwrapped.num_stages
    else:
        assert not episode.succeeded, f"{task} error {kind!r} still succeeded"
        onset = episode.error_onset
        assert 0 < onset < len(episode)
        assert not episode.error_label[:onset].any() and episode.error_label[onset:].all()
        assert episode.frame_labels()[onset + 1] == 1 and episode.frame_labels()[onset] == 0


def test_unknown_error_kind_is_named(make_env):
    env = make_env("AED-PickPlace-base", obs_mode="state")
    with pytest.raises(ValueError, match="unknown error kind 'juggle'"):
        solve(env, seed=0, error=ErrorSpec("juggle"))


@pytest.mark.parametrize("task", [t for t in ALL_TASKS if aed_tasks.get_task(t).recoverable_errors])
def test_suboptimal_demonstration_fails_first_then_succeeds(task, make_env):
    env = make_env(f"AED-{task}-base", obs_mode="state", demonstrator=True)
    clean = solve(env, seed=5, env_index=0)
    retried = solve(env, seed=5, env_index=0, suboptimal=True)
    assert retried.succeeded and retried.suboptimal and retried.role == "demo"
    assert not retried.error_label.any()
    assert len(retried) > len(clean)

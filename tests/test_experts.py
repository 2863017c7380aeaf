"""Every task's expert: clean episodes succeed, every injected error fails in its named way
(the task's `error_outcome` check, which a clean success must not pass), labels align."""

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
    assert not episode.truncated, f"{task} {kind or 'clean'}: the time limit cut the script"
    if kind is None:
        assert episode.succeeded, f"clean {task} expert failed (stage {episode.stage.max()})"
        assert episode.error_onset is None and not episode.error_label.any()
        assert episode.stage[-1] == env.unwrapped.num_stages
        for other in env.unwrapped.error_kinds:  # the outcome checks can fail: a success shows none
            assert env.unwrapped.error_outcome(other), f"a clean {task} success passes as {other!r}"
    else:
        assert not episode.succeeded, f"{task} error {kind!r} still succeeded"
        assert not episode.outcome_problem, (
            f"{task} {kind!r} did not fail as named: {episode.outcome_problem}"
        )
        onset = episode.error_onset
        assert 0 < onset < len(episode)
        assert not episode.error_label[:onset].any() and episode.error_label[onset:].all()
        assert episode.frame_labels()[onset + 1] == 1 and episode.frame_labels()[onset] == 0


@pytest.mark.parametrize("task", ALL_TASKS)
def test_expert_succeeds_in_the_novel_split(task, make_env):
    env = make_env(f"AED-{task}-novel", obs_mode="state")
    episode = solve(env, seed=12, env_index=5 % len(env.unwrapped.catalogue))
    assert episode.split == "novel" and episode.succeeded and not episode.truncated


def test_unknown_error_kind_is_named(make_env):
    env = make_env("AED-PickPlace-base", obs_mode="state")
    with pytest.raises(ValueError, match="unknown error kind 'juggle'"):
        solve(env, seed=0, error=ErrorSpec("juggle"))
    with pytest.raises(ValueError, match="unknown error kind 'juggle'"):
        env.unwrapped.error_outcome("juggle")


@pytest.mark.parametrize("task", [t for t in ALL_TASKS if aed_tasks.get_task(t).recoverable_errors])
def test_suboptimal_demonstration_fails_first_then_succeeds(task, make_env):
    env = make_env(f"AED-{task}-base", obs_mode="state", demonstrator=True)
    clean = solve(env, seed=5, env_index=0)
    retried = solve(env, seed=5, env_index=0, suboptimal=True)
    assert retried.succeeded and retried.suboptimal and retried.role == "demo"
    assert not retried.error_label.any()
    assert len(retried) > len(clean)
    # the first attempt failed, in its named way, before the second one started
    first = retried.first_attempt_steps
    assert retried.first_attempt_kind in env.unwrapped.recoverable_errors and 0 < first < len(
        retried
    )
    assert retried.first_attempt_problem == "" and not retried.success[:first].any()

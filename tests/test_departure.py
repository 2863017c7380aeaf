"""Labels at the visible departure: an intervened episode is its clean twin until the onset.

For every task and error kind, on seeds in both splits, the clean and the intervened episode
of one seed and environment have the same TCP and object positions up to the onset, the
action at the onset is the first that differs, and the two differ measurably within a few
steps of it (`aed_tasks.expert.departure`). Physics only (obs_mode="state"), one clean
episode per (task, seed) shared by the kinds.
"""

from __future__ import annotations

import numpy as np
import pytest

import aed_tasks
from aed_tasks import ErrorSpec
from aed_tasks.expert import DEPARTURE_APART, Trace, departure, trace_episode

# (seed, split, env index): seeds unused by the other expert tests, environments in both splits
EPISODES = ((31, "base", 4), (32, "novel", 7))
CASES = [
    (task, kind)
    for task in sorted(aed_tasks.TASKS)
    for kind in aed_tasks.get_task(task).error_kinds
]
_clean: dict[tuple[str, int], Trace] = {}


def _env(make_env, envs: dict, task: str, split: str):
    if (task, split) not in envs:
        envs[(task, split)] = make_env(aed_tasks.env_id(task, split), obs_mode="state")
    return envs[(task, split)]


@pytest.fixture(scope="module")
def envs():
    return {}


@pytest.mark.parametrize(("task", "kind"), CASES, ids=[f"{t}-{k}" for t, k in CASES])
def test_intervened_episode_departs_at_its_onset(task, kind, make_env, envs):
    for seed, split, index in EPISODES:
        env = _env(make_env, envs, task, split)
        index %= len(env.unwrapped.catalogue)
        if (task, seed) not in _clean:
            _clean[(task, seed)] = trace_episode(env, seed, None, index)[1]
        episode, trace = trace_episode(env, seed, ErrorSpec(kind), index)
        result = departure(_clean[(task, seed)], trace, episode.error_onset)
        assert not result.problem, (
            f"{task} {kind} ({split} env {index}, seed {seed}): {result.problem}"
        )


def _trace(tcp_x: list[float], gripper: float = 1.0) -> Trace:
    points = np.zeros((len(tcp_x), 2, 3))
    points[:, 0, 0] = tcp_x
    actions = np.zeros((len(tcp_x), 4))
    actions[:, 0] = np.diff([0.0, *tcp_x]) / 0.1
    actions[:, 3] = gripper
    return Trace(actions, points)


def test_departure_finds_early_and_invisible_onsets():
    clean = _trace([0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08])
    same = _trace([0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08])
    stops = _trace([0.0, 0.01, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02])
    assert not departure(clean, stops, 3).problem and departure(clean, stops, 3).after == 0
    assert "before the onset" in departure(clean, stops, 4).problem  # marked late
    assert "is the clean expert's" in departure(clean, stops, 2).problem  # marked early
    assert "is the clean expert's" in departure(clean, same, 3).problem  # nothing differs
    drift = _trace([0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08 + 2 * DEPARTURE_APART])
    drift.actions[2, 0] += 1e-3
    assert "no measurable difference" in departure(clean, drift, 2).problem  # apart only 6 steps on
    assert (
        departure(clean, _trace([0.0] * 9, gripper=-1.0), 0).after == 0
    )  # the gripper closes at once
    with pytest.raises(ValueError, match="onset 12 outside"):
        departure(clean, same, 12)

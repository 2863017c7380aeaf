"""Press Button specifics: the spring, the latched success, and what each error does to the cap."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from aed_tasks import ErrorSpec, solve
from aed_tasks.expert import ScriptedExpert, expert_speed


class DepthLog(gym.Wrapper):
    """Keeps the cap's press depth of every step (the expert sees the same steps)."""

    def reset(self, **kwargs):
        self.depths: list[float] = []
        return self.env.reset(**kwargs)

    def step(self, action):
        out = self.env.step(action)
        self.depths.append(float(out[-1]["press_depth"][0]))
        return out


@pytest.fixture(scope="module")
def env(make_env):
    return DepthLog(make_env("AED-PressButton-base", obs_mode="state"))


def test_spring_pops_the_cap_back_and_success_stays_latched(env):
    base = env.unwrapped
    env.reset(seed=0, options={"env_index": 2})
    travel = base.geometry.travel
    base.button.set_qpos(torch.tensor([[-travel]]))
    assert bool(base.evaluate()["success"][0])
    for _ in range(10):
        *_, info = env.step(np.zeros(4, np.float32))
    assert abs(float(info["press_depth"][0])) < 1e-3, "the cap did not come back up"
    assert bool(info["success"][0]) and int(info["stage"][0]) == 1
    env.reset(seed=1)
    assert not bool(base.evaluate()["success"][0])


def test_clean_press_reaches_the_bottom_of_the_travel(env):
    episode = solve(env, seed=3, env_index=5)
    assert episode.succeeded
    assert max(env.depths) >= env.unwrapped.geometry.travel - 0.002


def test_no_touch_never_moves_the_cap(env):
    episode = solve(env, seed=4, error=ErrorSpec("no_touch"), env_index=6)
    assert not episode.succeeded and max(env.depths) < 1e-4


def test_not_fully_pressed_moves_the_cap_partway(env):
    episode = solve(env, seed=5, error=ErrorSpec("not_fully_pressed"), env_index=7)
    travel = env.unwrapped.geometry.travel
    assert not episode.succeeded and 0.25 * travel < max(env.depths) < travel - 0.004
    # the press stops at the onset: the cap was already going down, and goes no deeper after it
    onset = episode.error_onset
    assert env.depths[onset - 1] > 0.2 * travel
    assert max(env.depths[onset:]) < env.depths[onset - 1] + 0.003


@pytest.mark.parametrize("kind", ["no_touch", "not_fully_pressed"])
def test_clean_script_recovers_after_each_recoverable_error(env, kind):
    base = env.unwrapped
    assert kind in base.recoverable_errors
    env.reset(seed=8, options={"env_index": 9})
    rng = np.random.default_rng(8)
    expert = ScriptedExpert(env, rng, expert_speed(rng, False))
    base.expert_script(expert, ErrorSpec(kind))
    assert not any(expert.success)
    base.expert_script(expert, None)  # the script runs to its end; success stays latched
    assert expert.success[-1] and not expert.truncated

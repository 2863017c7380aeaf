"""Factory Packing specifics: the expert rests while the belt delivers, and each error
kind's named outcome (`miss_belt` short of and past the belt)."""

from __future__ import annotations

import numpy as np
import pytest

from aed_tasks import ErrorSpec, solve
from aed_tasks.tasks.factory_packing import OUT_BELT_Y


@pytest.fixture(scope="module")
def env(make_env):
    return make_env("AED-FactoryPacking-base", obs_mode="state")


def test_clean_expert_rests_after_the_delivery(env):
    episode = solve(env, seed=48, env_index=4)
    assert episode.succeeded and not episode.truncated
    first = int(np.argmax(episode.success))
    assert len(episode) - first > 4, "the script ended before the box reached the destination"


@pytest.mark.parametrize("kind", ["product_not_in_box", "no_grasp_box"])
def test_each_error_ends_in_its_named_failure(env, kind):
    episode = solve(env, seed=49, error=ErrorSpec(kind), env_index=6)
    assert not episode.succeeded and not episode.truncated
    assert episode.outcome_problem == "", episode.outcome_problem


def test_miss_belt_leaves_the_box_off_the_belt_short_of_it_and_past_it(env):
    sides = set()
    for seed in (50, 51, 52, 53):
        episode = solve(env, seed=seed, error=ErrorSpec("miss_belt"), env_index=8)
        assert not episode.succeeded and not episode.truncated
        assert episode.outcome_problem == "", episode.outcome_problem
        sides.add(bool(env.unwrapped.box.pose.p[0, 1] > OUT_BELT_Y))
    assert sides == {True, False}, "seeds 50-53 no longer cover both misses"

"""Organize Table specifics: what "fully under" means, a canister that stays put, and each
error kind's named outcome."""

from __future__ import annotations

import numpy as np
import pytest
from mani_skill.utils.structs.pose import Pose

from aed_tasks import ErrorSpec, solve
from aed_tasks.objects.shelf import shelf_opening

CANISTER_ENV = 13  # a novel environment whose item is a canister (a drum lying along x)


@pytest.fixture(scope="module")
def env(make_env):
    return make_env("AED-OrganizeTable-base", obs_mode="state")


@pytest.fixture(scope="module")
def novel_env(make_env):
    return make_env("AED-OrganizeTable-novel", obs_mode="state")


def _put_item(base, dx: float, z: float) -> None:
    """The item's bottom centre `dx` from the target shelf's centre (x), at height `z`."""
    shelf = base.target_shelf.pose.p[0].cpu().numpy()
    base.item.set_pose(Pose.create_from_pq(p=[shelf[0] + dx, shelf[1], z]))


def test_fully_under_needs_every_corner_under_the_board_and_the_item_on_the_table(env):
    base = env.unwrapped
    env.reset(seed=41, options={"env_index": 5})
    half_depth = shelf_opening(base.env_spec.objects["target_shelf"])[1]
    length = base.env_spec.objects["item"].size[0]
    _put_item(base, 0.0, 0.0005)
    assert bool(base.evaluate()["success"][0])
    _put_item(base, 0.0, 0.05)  # under the board but held up in the air
    assert not bool(base.evaluate()["success"][0])
    _put_item(base, -half_depth + length / 2 - 0.01, 0.0005)  # 1 cm out of the mouth
    assert not bool(base.evaluate()["success"][0])
    assert base.error_outcome("not_fully_under") == ""
    _put_item(base, -half_depth - length, 0.0005)  # wholly in front of the shelf
    assert "no part" in base.error_outcome("not_fully_under")
    base.highest[:] = 0.0  # (the item held up above counted as lifted)
    assert "never carried" in base.error_outcome("drop_while_moving")
    base.highest[:] = 0.1  # as if carried: a drop in front of the shelf is no drop "away"
    assert "reached the target shelf" in base.error_outcome("drop_while_moving")


def test_a_canister_lying_on_the_table_does_not_roll_away(novel_env):
    base = novel_env.unwrapped
    novel_env.reset(seed=42, options={"env_index": CANISTER_ENV})
    assert base.env_spec.objects["item"].shape == "item_canister"
    roll = 0.1  # a lying PhysX cylinder rolled off from this, gaining speed
    base.item.set_pose(
        Pose.create_from_pq(p=[-0.2, 0.0, 0.0005], q=[np.cos(roll / 2), np.sin(roll / 2), 0, 0])
    )
    for _ in range(30):
        novel_env.step(np.array([0, 0, 0, 1], dtype=np.float32))
    assert abs(float(base.item.pose.p[0, 1])) < 0.005
    assert abs(float(base.item.pose.q[0, 1])) < 0.02  # back on a flat face


def test_clean_expert_pushes_the_canister_fully_under(novel_env):
    episode = solve(novel_env, seed=43, env_index=CANISTER_ENV)
    assert episode.succeeded and not episode.truncated


@pytest.mark.parametrize("kind", ["no_grasp", "drop_while_moving", "not_fully_under"])
def test_each_error_ends_in_its_named_failure(env, kind):
    episode = solve(env, seed=44, error=ErrorSpec(kind), env_index=9)
    assert not episode.succeeded and not episode.truncated
    assert episode.outcome_problem == "", episode.outcome_problem

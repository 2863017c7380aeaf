"""Back to Box specifics: "under the shelf" is measured against the board, and each error
kind's named outcome."""

from __future__ import annotations

import pytest
from mani_skill.utils.structs.pose import Pose

from aed_tasks import ErrorSpec, solve
from aed_tasks.objects.storage_box import SHELF_RECESS
from aed_tasks.tasks.back_to_box import MAX_OUT_OF_BOARD


@pytest.fixture(scope="module")
def env(make_env):
    return make_env("AED-BackToBox-base", obs_mode="state")


def _box_rear_at(base, out_of_board: float) -> None:
    """The box, square to the shelf, its rear `out_of_board` in front of the board."""
    shelf = base.shelf.pose.p[0].cpu().numpy()
    x = shelf[0] + SHELF_RECESS - out_of_board + base.box_geometry.depth / 2
    base.box.set_pose(Pose.create_from_pq(p=[x, shelf[1], 0.0005]))


def test_under_the_shelf_is_measured_against_the_board(env):
    base = env.unwrapped
    env.reset(seed=45, options={"env_index": 7})
    _box_rear_at(base, MAX_OUT_OF_BOARD - 0.005)
    assert bool(base.box_under_shelf()[0])
    # between the side panels, but 3.5 cm out of the board: under the old definition
    _box_rear_at(base, MAX_OUT_OF_BOARD + 0.005)
    assert not bool(base.box_under_shelf()[0])
    _box_rear_at(base, SHELF_RECESS)  # rear at the side panels' front edges: half out
    assert not bool(base.box_under_shelf()[0])


def test_clean_expert_leaves_the_box_under_the_board(env):
    episode = solve(env, seed=46, env_index=11)
    assert episode.succeeded and not episode.truncated
    assert float(env.unwrapped.box_out_of_board()[0]) <= MAX_OUT_OF_BOARD


@pytest.mark.parametrize("kind", ["no_grasp", "miss_box", "box_not_under"])
def test_each_error_ends_in_its_named_failure(env, kind):
    episode = solve(env, seed=47, error=ErrorSpec(kind), env_index=13)
    assert not episode.succeeded and not episode.truncated
    assert episode.outcome_problem == "", episode.outcome_problem

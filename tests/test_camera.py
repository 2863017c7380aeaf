"""The cameras see every task object at reset: the robot at its rest pose hides none of them.

Each task object's pixels are counted in the segmentation of both cameras, once as the
scene stands and once with the robot moved out of the way; the robot may hide only a sliver.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import sapien

from .conftest import ALL_TASKS

CAMERAS = ("front", "front_shift")
ROOM = {"floor", "wall", "table", "pillars"}
NOT_TASK_OBJECTS = re.compile(r"^(distractor_\d+|water_\d+)$")  # clutter, the glass's drops
MIN_PIXELS = 4  # at 160x120 the smallest object (Organize Table's item, seen through a shelf)
MIN_VISIBLE_SHARE = 0.9  # of an object's pixels with the robot gone


def task_object_ids(env) -> dict[int, str]:
    """Segmentation ids of the task's objects: all but the robot, the room and the clutter."""
    robot = {link.name for link in env.agent.robot.links}
    return {
        sid: entity.name
        for sid, entity in env.segmentation_id_map.items()
        if entity.name not in robot | ROOM and not NOT_TASK_OBJECTS.match(entity.name)
    }


def pixel_counts(obs: dict, ids: dict[int, str]) -> dict[tuple[str, str], int]:
    counts: dict[tuple[str, str], int] = {}
    for camera in CAMERAS:
        seg = obs["sensor_data"][camera]["segmentation"][0, ..., 0].cpu().numpy()
        for sid, name in ids.items():
            counts[camera, name] = counts.get((camera, name), 0) + int(np.count_nonzero(seg == sid))
    return counts


@pytest.mark.parametrize("split", ["base", "novel"])
@pytest.mark.parametrize("task", ALL_TASKS)
def test_task_objects_are_visible_at_reset(task, split, make_env):
    env = make_env(f"AED-{task}-{split}", obs_mode="rgb+segmentation", cameras=CAMERAS)
    for seed, index in ((1, 1), (2, 2)):
        obs, _ = env.reset(seed=seed, options={"env_index": index})
        base = env.unwrapped
        ids = task_object_ids(base)
        assert ids, f"{task} {split}: no task object in the segmentation map"
        seen = pixel_counts(obs, ids)
        rest = base.agent.robot.pose
        base.agent.robot.set_pose(sapien.Pose(p=[0.0, 0.0, -5.0]))  # under the floor
        free = pixel_counts(base.get_obs(), ids)
        base.agent.robot.set_pose(rest)
        for key, pixels in free.items():
            assert pixels >= MIN_PIXELS, (
                f"{task} {split} env {index}: {key} shows {pixels} px without the robot"
            )
            assert seen[key] >= MIN_VISIBLE_SHARE * pixels, (
                f"{task} {split} env {index}: the robot hides {key} "
                f"({seen[key]} of {pixels} px visible)"
            )

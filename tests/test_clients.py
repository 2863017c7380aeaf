"""ManiSkill's own clients on every registered AED id: the vector env its PPO and imitation
baselines use (`ManiSkillVectorEnv`), its trajectory recorder (`RecordEpisode`) and its replay
tool on what the recorder wrote; and Gymnasium's own vector envs (`SyncVectorEnv`,
`AsyncVectorEnv`) over the project's recreatable `CPUGymWrapper`."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from mani_skill.trajectory import replay_trajectory as replay
from mani_skill.utils.wrappers.record import RecordEpisode
from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

from aed_tasks.registration import CPUGymWrapper
from tests.conftest import ALL_IDS


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_maniskill_vector_env_steps_every_id(env_id):
    env = ManiSkillVectorEnv(
        gym.make(env_id, num_envs=1, obs_mode="state"),
        1,
        ignore_terminations=True,
        record_metrics=True,
    )
    try:
        obs, _ = env.reset(seed=0)
        assert obs.shape[0] == 1 and torch.isfinite(obs).all()
        action = torch.zeros(env.action_space.shape)
        obs, reward, terminated, truncated, info = env.step(action)
        assert obs.shape[0] == reward.shape[0] == 1 and "success" in info
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_maniskill_record_episode_writes_a_trajectory_of_every_id(env_id, tmp_path):
    env = RecordEpisode(
        gym.make(env_id, obs_mode="state"),
        output_dir=str(tmp_path),
        save_video=False,
        trajectory_name="traj",
        source_type="test",
    )
    try:
        env.reset(seed=0, options={"env_index": 0})
        for _ in range(3):
            env.step(env.action_space.sample() * 0)
    finally:
        env.close()
    meta = json.loads((tmp_path / "traj.json").read_text())
    assert meta["env_info"]["env_id"] == env_id and meta["episodes"][0]["elapsed_steps"] == 3
    assert (tmp_path / "traj.h5").stat().st_size > 0
    replay.main(
        replay.parse_args(
            [
                "--traj-path",
                str(tmp_path / "traj.h5"),
                "--use-env-states",
                "--obs-mode",
                "state",
                "--save-traj",
                "--allow-failure",
            ]
        )
    )
    replayed = [p for p in tmp_path.glob("traj.*.json")]
    assert len(replayed) == 1, sorted(p.name for p in tmp_path.iterdir())
    assert json.loads(replayed[0].read_text())["episodes"][0]["elapsed_steps"] == 3


def check_vector_steps(envs: gym.vector.VectorEnv, num_envs: int) -> None:
    """Reset two seeds, step once: batched numpy arrays of the single spaces, distinct episodes."""
    obs, _ = envs.reset(seed=[0, 1])
    assert envs.single_observation_space.contains(obs[0])
    assert obs.shape == (num_envs, *envs.single_observation_space.shape)
    assert np.isfinite(obs).all() and not np.array_equal(obs[0], obs[1])
    obs, reward, terminated, truncated, info = envs.step(np.zeros(envs.action_space.shape))
    assert obs.shape[0] == reward.shape[0] == terminated.shape[0] == truncated.shape[0] == num_envs
    assert info["success"].shape == (num_envs,) and np.isfinite(obs).all()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_sync_vector_env_steps_every_id(env_id):
    envs = gym.make_vec(
        env_id, 2, vectorization_mode="sync", wrappers=[CPUGymWrapper], obs_mode="state"
    )
    try:
        assert isinstance(envs, gym.vector.SyncVectorEnv)
        check_vector_steps(envs, 2)
    finally:
        envs.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_async_vector_env_steps_every_id(env_id):
    """Worker processes forked (physics only: a forked renderer hangs; with rendering use
    `context="spawn"`, which re-imports ManiSkill in each worker, about a minute here)."""
    envs = gym.make_vec(
        env_id,
        2,
        vectorization_mode="async",
        vector_kwargs={"context": "fork"},
        wrappers=[CPUGymWrapper],
        obs_mode="state",
    )
    try:
        assert isinstance(envs, gym.vector.AsyncVectorEnv)
        check_vector_steps(envs, 2)
    finally:
        envs.close()


def test_gymnasium_sync_vector_env_batches_rgbd():
    envs = gym.vector.SyncVectorEnv(
        [lambda: CPUGymWrapper(gym.make("AED-PressButton-novel", obs_mode="rgbd"))] * 2
    )
    try:
        obs, _ = envs.reset(seed=[0, 1])
        assert envs.observation_space.contains(obs)
        rgb, depth = (obs["sensor_data"]["front"][k] for k in ("rgb", "depth"))
        assert rgb.shape == (2, 120, 160, 3) and rgb.dtype == np.uint8
        assert depth.shape == (2, 120, 160, 1) and depth.dtype == np.int16
        assert not np.array_equal(rgb[0], rgb[1])  # two seeds, two scenes
        obs, reward, *_ = envs.step(np.zeros(envs.action_space.shape))
        assert reward.shape == (2,) and obs["sensor_data"]["front"]["rgb"].shape[0] == 2
    finally:
        envs.close()

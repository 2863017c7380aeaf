"""ManiSkill's own clients on every registered AED id: the vector env its PPO and imitation
baselines use (`ManiSkillVectorEnv`), its trajectory recorder (`RecordEpisode`) and its replay
tool on what the recorder wrote."""

from __future__ import annotations

import json

import gymnasium as gym
import pytest
import torch
from mani_skill.trajectory import replay_trajectory as replay
from mani_skill.utils.wrappers.record import RecordEpisode
from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

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

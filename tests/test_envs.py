"""Every registered AED env: the Gymnasium contract, observations, determinism, info."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

import aed_tasks
from aed_tasks.base_env import IMAGE_HEIGHT, IMAGE_WIDTH

from .conftest import ALL_IDS, ALL_TASKS

EXPECTED_TASKS = {"CloseDrawer", "PressButton", "PickPlace", "MoveGlassCup", "OrganizeTable", "BackToBox", "FactoryPacking"}


def test_ids_follow_the_naming_contract():
    assert set(ALL_TASKS) <= EXPECTED_TASKS
    for task in ALL_TASKS:
        assert f"AED-{task}-base" in ALL_IDS and f"AED-{task}-novel" in ALL_IDS
        assert gym.spec(f"AED-{task}-novel").kwargs["split"] == "novel"


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_make_reset_step_render(env_id, make_env):
    """gym.make(id) with no argument gives RGB-D 160x120 frames and the info contract."""
    env = make_env(env_id)
    obs, info = env.reset(seed=7)
    front = obs["sensor_data"]["front"]
    assert front["rgb"].shape == (1, IMAGE_HEIGHT, IMAGE_WIDTH, 3) and str(front["rgb"].dtype) == "torch.uint8"
    assert front["depth"].shape == (1, IMAGE_HEIGHT, IMAGE_WIDTH, 1) and str(front["depth"].dtype) == "torch.int16"
    rgb = front["rgb"][0].numpy()
    assert rgb.std() > 10, "the frame is blank"
    assert (front["depth"][0].numpy() > 0).mean() > 0.9, "depth has holes over most of the frame"
    assert env.action_space.shape == (4,)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    for key in ("success", "fail", "stage"):
        assert key in info, f"info lacks {key!r}"
    assert np.isfinite(obs["agent"]["qpos"].numpy()).all()
    assert 0 <= int(info["stage"][0]) <= env.unwrapped.num_stages


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_env_checker(env_id, make_env):
    env = CPUGymWrapper(make_env(env_id, obs_mode="state", env_index=0).unwrapped)
    check_env(env, skip_render_check=True, skip_close_check=True)  # both would rebuild the env
    obs, _ = env.reset(seed=1)
    assert np.isfinite(obs).all() and obs.dtype == np.float32


@pytest.mark.parametrize("task", ALL_TASKS)
def test_seeded_resets_are_deterministic(task, make_env):
    env = make_env(f"AED-{task}-base", env_index=1)
    actions = np.random.default_rng(0).uniform(-1, 1, (5, 4)).astype(np.float32)

    def rollout(seed):
        obs, _ = env.reset(seed=seed)
        frames = [obs["sensor_data"]["front"]["rgb"].numpy().copy()]
        for action in actions:
            obs, *_ = env.step(action)
            frames.append(obs["sensor_data"]["front"]["rgb"].numpy().copy())
        return np.stack(frames), env.unwrapped.get_state().numpy()

    frames_a, state_a = rollout(3)
    frames_b, state_b = rollout(3)
    frames_c, _ = rollout(4)
    np.testing.assert_array_equal(frames_a, frames_b)
    np.testing.assert_allclose(state_a, state_b, atol=1e-6)
    assert not np.array_equal(frames_a[0], frames_c[0]), "a different seed gave the same initial scene"


@pytest.mark.parametrize("task", ALL_TASKS)
def test_env_index_pins_and_reset_option_switches(task, make_env):
    env = make_env(f"AED-{task}-novel", obs_mode="state", env_index=2)
    env.reset(seed=0)
    assert env.unwrapped.env_index == 2
    env.reset(seed=0, options={"reconfigure": True})
    assert env.unwrapped.env_index == 2
    last = len(env.unwrapped.catalogue) - 1
    env.reset(seed=0, options={"env_index": last})
    assert env.unwrapped.env_index == last
    with pytest.raises(IndexError, match="out of range"):
        env.reset(seed=0, options={"env_index": last + 1})


def test_unknown_split_and_camera_are_named():
    with pytest.raises(ValueError, match="unknown split 'train'"):
        gym.make("AED-PickPlace-base", split="train")
    with pytest.raises(ValueError, match="unknown cameras"):
        gym.make("AED-PickPlace-base", cameras=("top",))
    with pytest.raises(KeyError, match="unknown task 'Juggle'"):
        aed_tasks.get_task("Juggle")


def test_shifted_viewpoint_renders_a_different_image(make_env):
    env = make_env("AED-PickPlace-novel", cameras=("front", "front_shift"), env_index=0)
    obs, _ = env.reset(seed=0)
    front, shifted = (obs["sensor_data"][c]["rgb"][0].numpy() for c in ("front", "front_shift"))
    assert shifted.shape == front.shape
    assert np.abs(front.astype(int) - shifted.astype(int)).mean() > 10


def test_demonstrator_looks_unlike_the_agent(make_env):
    agent = make_env("AED-PickPlace-base", env_index=0)
    expert = make_env("AED-PickPlace-base", env_index=0, demonstrator=True)
    a = agent.reset(seed=0)[0]["sensor_data"]["front"]["rgb"][0].numpy().astype(int)
    b = expert.reset(seed=0)[0]["sensor_data"]["front"]["rgb"][0].numpy().astype(int)
    changed = np.abs(a - b).sum(-1) > 60
    assert changed.mean() > 0.01, "the demonstrator's robot is not recoloured"


def test_cameras_render_with_the_cheap_shadow_filter(make_env, tmp_path, monkeypatch):
    from aed_tasks import rendering

    env = make_env("AED-PressButton-base", env_index=0)
    env.reset(seed=0)
    camera = env.unwrapped._sensors["front"]
    assert camera.config.shader_config.shader_pack == str(rendering.shader_pack_dir())
    assert "PCF_SampleCount = 4;" in (rendering.shader_pack_dir().parent / "common" / "shadow.glsl").read_text()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))  # a fresh cache is derived from SAPIEN's pack
    rendering.shader_pack_dir.cache_clear()
    try:
        fresh = rendering.shader_pack_dir()
        assert fresh.is_relative_to(tmp_path) and (fresh / "gbuffer.frag").exists()
    finally:
        rendering.shader_pack_dir.cache_clear()

"""Every registered AED env: the Gymnasium contract, observations, determinism, info."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from mani_skill.utils import gym_utils
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper as ManiSkillCPUGymWrapper

import aed_tasks
from aed_tasks.base_env import IMAGE_HEIGHT, IMAGE_WIDTH
from aed_tasks.expert import solve
from aed_tasks.registration import CPUGymWrapper

from .conftest import ALL_IDS, ALL_TASKS

EXPECTED_TASKS = {
    "CloseDrawer",
    "PressButton",
    "PickPlace",
    "MoveGlassCup",
    "OrganizeTable",
    "BackToBox",
    "FactoryPacking",
}


def test_ids_follow_the_naming_contract():
    assert set(ALL_TASKS) == EXPECTED_TASKS, (
        "a task stopped registering, or a new one is not listed here"
    )
    assert (
        len(aed_tasks.PAPER_TASK_ORDER) == 7 and set(aed_tasks.PAPER_TASK_ORDER) == EXPECTED_TASKS
    )
    for task in ALL_TASKS:
        assert f"AED-{task}-base" in ALL_IDS and f"AED-{task}-novel" in ALL_IDS
        assert gym.spec(f"AED-{task}-novel").kwargs["split"] == "novel"


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_make_reset_step_render(env_id, make_env):
    """gym.make(id) with no argument gives RGB-D 160x120 frames and the info contract."""
    env = make_env(env_id)
    obs, info = env.reset(seed=7)
    front = obs["sensor_data"]["front"]
    assert (
        front["rgb"].shape == (1, IMAGE_HEIGHT, IMAGE_WIDTH, 3)
        and str(front["rgb"].dtype) == "torch.uint8"
    )
    assert (
        front["depth"].shape == (1, IMAGE_HEIGHT, IMAGE_WIDTH, 1)
        and str(front["depth"].dtype) == "torch.int16"
    )
    rgb = front["rgb"][0].numpy()
    assert rgb.std() > 10, "the frame is blank"
    assert (front["depth"][0].numpy() > 0).mean() > 0.9, "depth has holes over most of the frame"
    assert env.action_space.shape == (4,)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    for key in ("success", "fail", "stage"):
        assert key in info, f"info lacks {key!r}"
    assert np.isfinite(obs["agent"]["qpos"].numpy()).all()
    assert 0 <= int(info["stage"][0]) <= env.unwrapped.num_stages


@pytest.mark.filterwarnings(
    "ignore:.*is different from the unwrapped version"
)  # wrapped on purpose
@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_env_checker(env_id, make_env):
    """Gymnasium's checker on the env as users make it for CPU use, closing included.

    The close check rebuilds the env from `env.spec`. The render check would too, once per
    render mode, and `human` opens a viewer window (no display here): it alone is skipped.
    """
    env = CPUGymWrapper(make_env(env_id, obs_mode="state", env_index=0))
    assert isinstance(env, ManiSkillCPUGymWrapper)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert np.isfinite(obs).all() and obs.dtype == np.float32


def test_an_env_is_rebuilt_from_its_spec_with_its_time_limit(make_env):
    env = make_env("AED-PressButton-base", obs_mode="state", max_episode_steps=3)
    assert gym_utils.find_max_episode_steps_value(env) == 3
    again = make_env(env.spec)
    assert (
        again.spec.kwargs == env.spec.kwargs and gym_utils.find_max_episode_steps_value(again) == 3
    )
    again.reset(seed=0)
    truncated = [again.step(np.zeros(4, np.float32))[3] for _ in range(3)]
    assert all(
        isinstance(t, torch.Tensor) and t.shape == (1,) for t in truncated
    )  # ManiSkill's batched type
    assert [bool(t[0]) for t in truncated] == [False, False, True]
    default = make_env("AED-PressButton-base", obs_mode="state")
    assert (
        gym_utils.find_max_episode_steps_value(default)
        == aed_tasks.get_task("PressButton").max_episode_steps
    )


@pytest.mark.parametrize("terminate_on_success", [True, False])
def test_success_is_latched_and_ends_the_episode_only_if_asked(
    terminate_on_success, make_env, monkeypatch
):
    env = make_env(
        "AED-PressButton-base",
        obs_mode="state",
        env_index=0,
        terminate_on_success=terminate_on_success,
    )
    base = env.unwrapped
    evaluate = base.evaluate

    def succeeds_at_step_2():
        info = evaluate()
        info["success"] = base.elapsed_steps == 2  # and no longer after it
        return info

    monkeypatch.setattr(base, "evaluate", succeeds_at_step_2)
    env.reset(seed=0)
    steps = [env.step(np.zeros(4, np.float32)) for _ in range(4)]
    assert [bool(info["success"][0]) for *_, info in steps] == [False, True, True, True]
    terminated = [bool(step[2][0]) for step in steps]
    assert terminated == [False] + [terminate_on_success] * 3
    _, info = env.reset(seed=0)
    assert not bool(info["success"][0]), "the latch outlived its episode"


def test_solve_runs_the_script_to_its_end_whatever_the_termination(make_env):
    """Successes end like failures: retreat and rest after the success, in both settings."""
    episodes = [
        solve(
            make_env("AED-PressButton-base", obs_mode="state", terminate_on_success=t),
            seed=3,
            env_index=1,
        )
        for t in (True, False)
    ]
    for episode in episodes:
        first = int(np.argmax(episode.success))
        assert episode.succeeded and not episode.truncated and episode.success[first:].all()
        assert len(episode) - first > 4 + 2, "no retreat after the success"
        assert not episode.actions[-4:, :3].any(), "the episode does not end at rest (wait(4))"
    np.testing.assert_array_equal(episodes[0].actions, episodes[1].actions)


def test_solve_marks_an_episode_the_time_limit_cut(make_env):
    episode = solve(
        make_env("AED-PressButton-base", obs_mode="state", max_episode_steps=20),
        seed=3,
        env_index=1,
    )
    assert episode.truncated and len(episode) == 20


def test_batched_simulation_is_refused_with_a_way_out():
    with pytest.raises(
        ValueError, match=r"num_envs=2: AED tasks run one env per process.*--workers"
    ):
        gym.make("AED-PickPlace-base", num_envs=2)


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
    assert not np.array_equal(frames_a[0], frames_c[0]), (
        "a different seed gave the same initial scene"
    )


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
    assert (
        "PCF_SampleCount = 4;"
        in (rendering.shader_pack_dir().parent / "common" / "shadow.glsl").read_text()
    )
    monkeypatch.setenv(
        "XDG_CACHE_HOME", str(tmp_path)
    )  # a fresh cache is derived from SAPIEN's pack
    rendering.shader_pack_dir.cache_clear()
    try:
        fresh = rendering.shader_pack_dir()
        assert fresh.is_relative_to(tmp_path) and (fresh / "gbuffer.frag").exists()
    finally:
        rendering.shader_pack_dir.cache_clear()

"""The online monitor: its scores equal the detector's offline scores; stop and correct on alarm."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from aed_eval.monitor import SAFE_TCP, AEDMonitor
from aed_models.data import proprio_from_obs, to_frames
from aed_models.detectors import make_detector
from aed_models.detectors.postprocess import postprocess
from aed_models.nn import VisualHeadConfig
from aed_models.policies import POLICIES, make_policy

ENV_ID = "AED-PressButton-novel"


@pytest.fixture(scope="module")
def env():
    env = gym.make(ENV_ID, env_index=0)
    yield env
    env.close()


@pytest.fixture(scope="module")
def policy():
    torch.manual_seed(0)
    config = POLICIES.preset(
        "scan",
        "mini",
        visual=VisualHeadConfig(arch="small_cnn", out_dim=16, width=4),
        localizer=None,
        subgoal_head="linear",  # the pointer head needs a localizer
    )
    return make_policy("scan", config).eval()


@pytest.fixture(scope="module")
def demos():
    generator = torch.Generator().manual_seed(1)
    mask = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    return {
        "frames": torch.rand(2, 6, 4, 120, 160, generator=generator),
        "mask": mask,
        "proprio": torch.rand(2, 6, 5, generator=generator),
    }


def tiny_detector(name: str, policy) -> torch.nn.Module:
    torch.manual_seed(2)
    if name == "probe":
        return make_detector(
            name,
            history_dim=policy.history_dim,
            task_dim=policy.task_dim,
            hidden_dim=16,
            embed_dim=8,
        ).eval()
    sizes = {"hidden_dim": 16} if name == "lstm_ed" else {}
    return make_detector(name, arch="small_cnn", feature_dim=16, width=4, **sizes).eval()


def observed_frames(observations: list) -> torch.Tensor:
    rgb = np.concatenate([o["sensor_data"]["front"]["rgb"].numpy() for o in observations])
    depth = np.concatenate([o["sensor_data"]["front"]["depth"].numpy() for o in observations])
    return to_frames(rgb, depth)


def observed_proprio(observations: list) -> torch.Tensor:
    return torch.from_numpy(
        np.concatenate(
            [proprio_from_obs(o["extra"]["tcp_pose"], o["agent"]["qpos"]) for o in observations]
        )
    )


@pytest.mark.parametrize("name", ["probe", "lstm_ed", "svdd_ed"])
def test_online_scores_equal_offline_scores(env, policy, demos, name):
    """svdd_ed: without memory, both sides take the running maximum (one post-processing)."""
    detector = tiny_detector(name, policy)
    monitor = AEDMonitor(env, policy, detector, demos, threshold=float("inf"), on_alarm="none")
    obs, info = monitor.reset(seed=3)
    observations, latencies = [obs], [info["aed_latency_s"]]
    for _ in range(8):
        obs, _, _, _, info = monitor.step(None)
        observations.append(obs)
        latencies.append(info["aed_latency_s"])
        assert (
            not info["aed_alarm"]
            and info["aed_env_step_s"] > 0
            and info["aed_policy_latency_s"] > 0
        )
    frames = observed_frames(observations)[None]
    mask = torch.ones(frames.shape[:2], dtype=torch.bool)
    assert (
        policy.config.proprio
    )  # the mini policy reads the TCP and fingers from the live observation
    with torch.inference_mode():
        features = (
            policy.features(frames, mask, demos, proprio=observed_proprio(observations)[None])
            if detector.requires_policy
            else None
        )
        per_frame = detector.score({"frames": frames, "mask": mask}, demos, features)
        offline = postprocess(detector, per_frame, mask)[0].numpy()
    np.testing.assert_allclose(monitor.scores, offline, atol=1e-5)
    assert all(latency >= 0 for latency in latencies)


def test_alarm_stops_the_episode(env, policy, demos):
    monitor = AEDMonitor(
        env, policy, tiny_detector("probe", policy), demos, threshold=-np.inf, on_alarm="stop"
    )
    _, info = monitor.reset(seed=3)
    assert info["aed_alarm"]
    _, _, _, truncated, info = monitor.step(None)
    assert truncated and info["aed_alarm"]


def test_alarm_hands_over_to_the_correction_once(env, policy, demos):
    monitor = AEDMonitor(
        env, policy, tiny_detector("probe", policy), demos, threshold=-np.inf, on_alarm="correct"
    )
    monitor.reset(seed=3)
    _, _, _, truncated, info = monitor.step(None)
    assert info["aed_corrected"] and info["aed_corrections"] == 1 and not truncated
    tcp = env.unwrapped.agent.tcp.pose.p[0].numpy()
    assert np.linalg.norm(tcp - SAFE_TCP) < 0.03, tcp
    _, _, _, _, info = monitor.step(None)  # later alarms are only reported
    assert info["aed_alarm"] and info["aed_corrections"] == 1 and "aed_corrected" not in info


def test_bad_on_alarm_is_named(env, policy, demos):
    with pytest.raises(ValueError, match="on_alarm='explode'"):
        AEDMonitor(
            env, policy, tiny_detector("probe", policy), demos, threshold=0.5, on_alarm="explode"
        )

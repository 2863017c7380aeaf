"""The scene encoder: scene state from stored env states, training (the loss falls, resume is
exact), localization errors, cached features, and policies that train on a frozen encoder."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from aed_models.data import EnvironmentIterations, load_episodes, scene_state, scene_state_names
from aed_models.encoder import EncoderConfig, load_encoder
from aed_models.nn import VisualHeadConfig
from aed_models.policies import POLICIES, load_policy
from aed_models.train.encoder import (
    TrainEncoderConfig,
    localization_errors,
    read_scene_state,
    state_loss,
    train_encoder,
)
from aed_models.train.frame_features import frame_features
from aed_models.train.policy import TrainPolicyConfig, train_policy
from tests.helpers import load_script, recorded_episode, write_synthetic_collection

H, W = 32, 40
TINY_VISUAL = VisualHeadConfig(arch="small_cnn", out_dim=16, width=4, dropout=0.0)
TINY = EncoderConfig(visual=TINY_VISUAL)


def synthetic(role: str, env_index: int, seed: int, steps: int):
    """A white square at (bx, by) on the table, recorded as the actor `button` (x = bx, y = by),
    beside clutter (`distractor_0`) and the robot (`panda`), which the scene state leaves out.
    The TCP moves toward the square; actions point at it."""
    rng = np.random.default_rng(seed)
    bx, by = rng.uniform(0.0, 1.0, 2)
    t = np.linspace(0.0, 1.0, steps + 1)[:, None]
    tcp_xy = (1 - t) * 0.5 + t * np.array([bx, by])
    rgb = np.zeros((steps + 1, H, W, 3), np.uint8)
    col, row = int(bx * (W - 8)), int(by * (H - 8))
    rgb[:, row : row + 8, col : col + 8] = 255
    depth = np.full((steps + 1, H, W, 1), 500, np.int16)
    tcp_pose = np.zeros((steps + 1, 7), np.float32)
    tcp_pose[:, :2], tcp_pose[:, 2], tcp_pose[:, 3] = tcp_xy, 0.2, 1.0
    actor = np.zeros((steps + 1, 13), np.float32)
    actor[:, 0], actor[:, 1], actor[:, 3] = bx, by, 1.0
    actions = np.concatenate([np.diff(tcp_xy, axis=0) * 10, np.zeros((steps, 2))], axis=1)
    states = {
        "actors": {"button": actor, "distractor_0": actor * 0},
        "articulations": {"panda": np.zeros((steps + 1, 31), np.float32)},
    }
    return recorded_episode(
        "PressButton", role, env_index, seed, rgb, depth, actions, tcp_pose, env_states=states
    )


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> Path:
    """Three environments; per env 2 demos and 3 agent successes of 6..10 steps."""
    return write_synthetic_collection(
        tmp_path_factory.mktemp("encoder_data"),
        {"demo": 2, "agent_success": 3},
        envs=(0, 1, 2),
        steps=6,
        make_episode=synthetic,
        demo_seed_offset=10,
    )


def encoder_config(collection: Path, out: Path, **kw) -> TrainEncoderConfig:
    base = {"data": collection, "out": out, "progress": False, "num_envs": 0, "lr": 1e-2}
    return TrainEncoderConfig.from_preset("PressButton", "mini", **{**base, **kw})


@pytest.fixture(scope="module")
def encoder_path(collection, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("encoder")
    return train_encoder(encoder_config(collection, out, epochs=8, batch_episodes=1), TINY)


def test_scene_state_is_the_task_objects_without_robot_and_clutter(collection):
    ref = load_episodes(collection)[0]
    with h5py.File(ref.path) as h5:
        names, state = scene_state_names(h5[ref.traj]), scene_state(h5[ref.traj])
        actor = h5[ref.traj]["env_states/actors/button"][()]
    assert names == [*(f"tcp.{a}" for a in "xyz"), *(f"subgoal.{a}" for a in "xyz")] + [
        f"button.{a}" for a in "xyz"
    ]
    assert state.shape == (ref.num_frames, 9) and np.array_equal(state[:, 6:], actor[:, :3])


def particle_episode(h5: h5py.File, drops: int) -> h5py.Group:
    """An episode of 3 frames whose scene holds a glass and `drops` water drops at heights
    0.01 * (1, 2, ...), beside the robot and clutter."""
    g = h5.create_group(f"traj_{drops}")
    g["obs/extra/tcp_pose"] = np.zeros((3, 7), np.float32)
    g["stage"] = np.zeros(2, np.int64)
    pose = np.zeros((3, 13), np.float32)
    for name in ("panda", "distractor_0", "glass"):
        g[f"env_states/actors/{name}"] = pose
    for i in range(drops):
        g[f"env_states/actors/water_{i}"] = pose + np.eye(13, dtype=np.float32)[2] * 0.01 * (i + 1)
    return g


def test_a_scenes_particles_are_one_object_whatever_their_number(tmp_path):
    with h5py.File(tmp_path / "particles.h5", "w") as h5:
        few, many = particle_episode(h5, 3), particle_episode(h5, 12)
        names = scene_state_names(few)
        assert names == scene_state_names(many) and names[-6:] == [
            *(f"glass.{a}" for a in "xyz"),
            *(f"water.{a}" for a in "xyz"),
        ]
        assert scene_state(few).shape == scene_state(many).shape == (3, 12)
        assert np.allclose(scene_state(few)[:, -1], 0.02)  # the centroid of 0.01, 0.02, 0.03
        assert np.allclose(scene_state(many)[:, -1], 0.065)


def test_episodes_with_other_task_objects_are_refused_by_name(tmp_path):
    from aed_models.train.encoder import SceneFrames

    def lid_in_env_1(role: str, env_index: int, seed: int, steps: int):
        meta, episode = synthetic(role, env_index, seed, steps)
        if env_index == 1:
            episode.env_states["actors"]["lid"] = episode.env_states["actors"]["button"]
        return meta, episode

    odd = write_synthetic_collection(
        tmp_path, {"demo": 1}, envs=(0, 1), steps=4, make_episode=lid_in_env_1
    )
    with pytest.raises(ValueError, match=r"env001.* a scene state of 12 columns, 9 in .*env000"):
        SceneFrames(load_episodes(odd))


def test_encoder_learns_where_the_square_is(encoder_path, collection):
    log = json.loads((encoder_path.parent / "train_log.json").read_text())
    assert [e["epoch"] for e in log] == list(range(1, 9))
    assert log[-1]["state_mse"] < 0.6 * log[0]["state_mse"], log
    encoder = load_encoder(encoder_path)
    assert encoder.config.state_names[-3:] == ("button.x", "button.y", "button.z")
    episodes = load_episodes(collection)
    errors = localization_errors(encoder, episodes, every=2)
    assert set(errors) == {"tcp", "subgoal", "button"}
    positions = []
    for ref in episodes:
        with h5py.File(ref.path) as h5:
            positions.append(h5[ref.traj]["env_states/actors/button"][0, :2])
    positions = np.array(positions)
    mean_error = 100 * np.linalg.norm(positions - positions.mean(0), axis=1).mean()
    assert errors["button"] < 0.8 * mean_error, (errors, mean_error)  # not the mean's guess


def test_exploration_frames_train_the_encoder_without_a_stage_target(collection, tmp_path):
    """Exploration episodes (`aed collect --num-explore`) label where things are but have no
    stage target: it is NaN in their scene state and left out of the loss and the statistics."""
    explore = write_synthetic_collection(
        tmp_path / "explore", {"explore": 2}, envs=(0, 1), steps=6, make_episode=synthetic
    )
    ref = load_episodes(explore)[0]
    state = read_scene_state(ref)
    assert ref.role == "explore" and np.isnan(state[:, 3:6]).all()
    assert np.isfinite(np.delete(state, [3, 4, 5], axis=1)).all()
    for shard in collection.glob("*_env00[01]_*"):  # the experts' episodes of the same envs
        (explore / shard.name).symlink_to(shard)
    path = train_encoder(encoder_config(explore, tmp_path / "encoder", epochs=2), TINY)
    log = json.loads((path.parent / "train_log.json").read_text())
    encoder = load_encoder(path)
    assert all(np.isfinite(e["state_mse"]) for e in log)
    assert torch.isfinite(encoder.state_mean).all() and torch.isfinite(encoder.state_std).all()
    experts = [r for r in load_episodes(explore) if r.role != "explore"]
    stage_target = state_loss(
        torch.zeros(1, 9), torch.from_numpy(read_scene_state(experts[0])[:1]), encoder
    )
    assert torch.isfinite(stage_target)
    errors = localization_errors(encoder, load_episodes(explore), every=2)
    assert all(np.isfinite(v) for v in errors.values()), errors


def test_encoder_resume_gives_the_same_weights(collection, tmp_path):
    whole = train_encoder(encoder_config(collection, tmp_path / "whole", epochs=2), TINY)
    train_encoder(encoder_config(collection, tmp_path / "split", epochs=1), TINY)
    resumed = train_encoder(encoder_config(collection, tmp_path / "split", epochs=2), TINY)
    a, b = load_encoder(whole).state_dict(), load_encoder(resumed).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="trained with seed=0, this run asks 1"):
        train_encoder(encoder_config(collection, tmp_path / "split", epochs=3, seed=1), TINY)
    with pytest.raises(ValueError, match="profile='paper'"):
        TrainEncoderConfig.from_preset("PressButton", "paper", data=collection, out=tmp_path)


def test_features_are_cached_and_equal_the_visual_head(encoder_path, collection, tmp_path):
    encoder = load_encoder(encoder_path)
    episodes = load_episodes(collection)
    features = frame_features(encoder.visual, encoder.sha256, episodes, tmp_path, progress=False)
    ref = episodes[0]
    with torch.no_grad():
        from aed_models.data import EpisodeReader

        direct = encoder.visual(EpisodeReader().read(ref).frames).numpy()
    assert np.allclose(features[str(ref.path), ref.traj], direct, atol=1e-6)
    (cached,) = list(tmp_path.glob("*/*/demo_env000_0000.npz"))
    stamp = cached.stat().st_mtime_ns
    again = frame_features(encoder.visual, encoder.sha256, episodes, tmp_path, progress=False)
    assert cached.stat().st_mtime_ns == stamp  # read, not recomputed
    assert all(np.array_equal(again[k], features[k]) for k in features)
    first = [e for e in episodes if e.path.name == "demo_env000_0000.h5"]
    other = frame_features(encoder.visual, "f" * 64, first[:1], tmp_path, progress=False)
    assert len(list(tmp_path.glob("*/*/demo_env000_0000.npz"))) == 2 and len(other) == 1
    more = frame_features(encoder.visual, "f" * 64, first, tmp_path, progress=False)
    assert len(more) == 2 and np.array_equal(more[next(iter(other))], next(iter(other.values())))
    (added,) = [p for p in tmp_path.glob("*/*/demo_env000_0000.npz") if p != cached]
    assert len(np.load(added).files) == 3  # the second episode added to the first's file
    data = EnvironmentIterations(episodes, "policy", features=features)
    rollouts = data[0]["rollouts"]
    assert "frames" not in rollouts and rollouts["features"].shape[-1] == TINY_VISUAL.out_dim


@pytest.mark.parametrize("name", ["naive_dc", "dct", "scan"])
def test_policies_train_on_a_frozen_encoder(name, encoder_path, collection, tmp_path):
    tiny = {"dct": {"num_heads": 4, "ff_dim": 32}, "scan": {"lstm_hidden": 12, "attention_dim": 8}}
    config = POLICIES.preset(
        name,
        "mini",
        visual=TINY_VISUAL,
        actor_hidden=(16, 8),
        frozen_encoder=True,
        localizer=None,
        subgoal_head="linear",  # the pointer head needs a localizer
        **tiny.get(name, {}),
    )
    cfg = TrainPolicyConfig.from_preset(
        "PressButton",
        name,
        "mini",
        data=collection,
        out=tmp_path / name,
        encoder=encoder_path,
        epochs=2,
        progress=False,
        num_envs=0,
        composition=(2, 2),
    )
    policy = load_policy(train_policy(cfg, config))
    encoder = load_encoder(encoder_path)
    a, b = policy.visual.state_dict(), encoder.visual.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)  # frozen: exactly the encoder's head
    assert torch.load(cfg.out / "policy.pt", weights_only=True)["extra"]["encoder_sha256"] == (
        encoder.sha256
    )
    with pytest.raises(FileNotFoundError, match="aed train-encoder"):
        train_policy(
            TrainPolicyConfig.from_preset(
                "PressButton",
                name,
                "mini",
                data=collection,
                out=tmp_path / "x",
                encoder=tmp_path / "missing.pt",
                progress=False,
            ),
            config,
        )


def test_localization_probe_reports_errors_beside_the_mean_guess(
    encoder_path, collection, tmp_path
):
    probe = load_script("localization_probe")
    table = probe.main(
        probe.Config(encoder=encoder_path, data=[collection], envs=(2,), out=tmp_path / "t.json")
    )
    (row,) = table.values()
    assert row["episodes"] == 5 and set(row["errors"]) == set(row["mean_guess"]) == {
        "tcp",
        "subgoal",
        "button",
    }
    assert json.loads((tmp_path / "t.json").read_text()) == table
    first = probe.main(
        probe.Config(encoder=encoder_path, data=[collection], roles=("demo",), every=1000)
    )
    (row,) = first.values()
    assert row["episodes"] == 2 * 3  # the demonstrations of the three environments, frame 0 each

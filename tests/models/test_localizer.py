"""The target localizer: geometry, stage points, training that finds unseen colours from the
demonstrations, and the policies that read it (online = batched, training, checkpoints)."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from aed_models.data import (
    DEPTH_SCALE_MM,
    EpisodeReader,
    load_episodes,
    pad_sequences,
    stage_end_points,
    stage_subgoals,
)
from aed_models.localizer import LocalizerConfig, load_localizer, modeling_localizer
from aed_models.localizer.modeling_localizer import (
    StageQueries,
    TargetLocalizer,
    colour_jitter,
    nearest_surface,
    refined_pixels,
)
from aed_models.nn import VisualHeadConfig
from aed_models.policies import POLICIES, load_policy, make_policy
from aed_models.policies.base import DCPolicy
from aed_models.train.localizer import (
    TrainLocalizerConfig,
    located_points,
    stage_episode,
    train_localizer,
)
from aed_models.train.policy import TrainPolicyConfig, train_policy
from tests.helpers import load_script, recorded_episode, write_synthetic_collection

H, W = 64, 80
FOCAL, HEIGHT_M = 60.0, 1.0  # a camera looking straight down from 1 m
INTRINSIC = np.array([[FOCAL, 0, W / 2], [0, FOCAL, H / 2], [0, 0, 1]], np.float32)
EXTRINSIC = np.array([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, HEIGHT_M]], np.float32)
TOP_M = 0.02  # the squares' height
TINY = LocalizerConfig(width=8, dim=8)


def pixel(x: float, y: float) -> tuple[int, int]:
    return int(FOCAL * x + W / 2), int(-FOCAL * y + H / 2)


def colours(env_index: int, split: str) -> tuple[np.ndarray, np.ndarray]:
    """The target square's colour and a distractor's; the novel split's are never the base's."""
    hue = np.random.default_rng([env_index, split == "novel"]).uniform(0.3, 1.0, 3)
    return (255 * hue).astype(np.uint8), (255 * (1.0 - hue) * 0.8).astype(np.uint8)


def make_maker(split: str = "base"):
    def synthetic(role: str, env_index: int, seed: int, steps: int):
        """A target square (the `button`) and a distractor on a table 1 m below the camera; the
        TCP descends onto the target, which completes the task's one stage two steps before
        the end, then lifts."""
        rng = np.random.default_rng(seed)
        (bx, by), (dx, dy) = rng.uniform([-0.2, -0.15], [0.2, 0.15], (2, 2))
        target, distractor = colours(env_index, split)
        rgb = np.full((steps + 1, H, W, 3), 40, np.uint8)
        depth = np.full((steps + 1, H, W, 1), 1000, np.int16)
        for (x, y), colour in (((dx, dy), distractor), ((bx, by), target)):
            u, v = pixel(x, y)
            rgb[:, v - 3 : v + 3, u - 3 : u + 3] = colour
            depth[:, v - 3 : v + 3, u - 3 : u + 3] = int(1000 * (HEIGHT_M - TOP_M))
        t = np.linspace(0.0, 1.0, steps)[:, None]
        tcp = np.zeros((steps + 1, 7), np.float32)
        tcp[:steps, :3] = (1 - t) * np.array([0.0, 0.0, 0.3]) + t * np.array([bx, by, TOP_M])
        tcp[steps, :3] = bx, by, 0.1
        tcp[:, 3] = 1.0
        button = np.zeros((steps + 1, 15), np.float32)
        button[:, :3] = bx, by, 0.0
        actions = np.zeros((steps, 4), np.float32)
        actions[:, :3] = np.diff(tcp[:, :3], axis=0) * 10
        camera = {
            "intrinsic_cv": np.tile(INTRINSIC, (steps + 1, 1, 1)),
            "extrinsic_cv": np.tile(EXTRINSIC, (steps + 1, 1, 1)),
        }
        stage = (np.arange(steps) >= steps - 2).astype(np.int16)
        return recorded_episode(
            "PressButton", role, env_index, seed, rgb, depth, actions, tcp,
            {"articulations": {"button": button}}, split=split, sensor_param=camera, stage=stage,
        )  # fmt: skip

    return synthetic


synthetic = make_maker("base")


@pytest.fixture(scope="module")
def collections(tmp_path_factory):
    root = tmp_path_factory.mktemp("localizer")
    base = write_synthetic_collection(
        root / "base", {"demo": 3, "agent_success": 3}, envs=tuple(range(8)), steps=5,
        step_increment=1, make_episode=make_maker("base"), demo_seed_offset=50,
    )  # fmt: skip
    novel = write_synthetic_collection(
        root / "novel", {"demo": 4}, envs=(0, 1, 2), steps=5, step_increment=1,
        make_episode=make_maker("novel"),
    )  # fmt: skip
    return base, novel


def localizer_config(base, out, **kw) -> TrainLocalizerConfig:
    recipe = {"epochs": 3, "updates": 50, "batch": 8, "max_frames": 3, "colour": 0.0}
    return TrainLocalizerConfig.from_preset(
        "PressButton", data=base, out=out, num_envs=0, progress=False, **{**recipe, **kw}
    )


@pytest.fixture(scope="module")
def localizer_path(collections, tmp_path_factory):
    out = tmp_path_factory.mktemp("trained")
    return train_localizer(localizer_config(collections[0], out), TINY)


def camera_localizer(config: LocalizerConfig = TINY) -> TargetLocalizer:
    localizer = TargetLocalizer(config)
    localizer.set_camera(torch.from_numpy(INTRINSIC), torch.from_numpy(EXTRINSIC))
    return localizer


def test_geometry_round_trips():
    localizer = camera_localizer()
    point = torch.tensor([[0.1, -0.05, 0.0]])  # on the table, 1 m below the camera
    uv = localizer.project(point)
    assert torch.allclose(uv, torch.tensor([[W / 2 + 6.0, H / 2 + 3.0]]))
    assert torch.allclose(localizer.unproject(uv, torch.tensor([HEIGHT_M])), point, atol=1e-6)
    logits = torch.full((2, 4, 5), -10.0)
    logits[0, 2, 3] = 10.0
    logits[1, 1, 1] = logits[1, 1, 2] = 10.0  # a tie: the refinement lands between the cells
    for stride in (4, 8):
        pixels = refined_pixels(logits, stride)
        assert torch.allclose(pixels[0], torch.tensor([3.5 * stride, 2.5 * stride]))
        assert torch.allclose(pixels[1], torch.tensor([2.0 * stride, 1.5 * stride]))


def test_a_match_beside_an_object_reads_the_object_depth():
    """A pixel two off a box's silhouette reads the table through the pixel itself, the box
    within a window of 4; pixels without depth (0) are never the nearest."""
    depth = torch.full((1, 20, 20), 1000.0)
    depth[0, 8:12, 8:12] = 980.0
    depth[0, 0, :] = 0.0
    assert nearest_surface(depth, 0)[0, 10, 14] == 1000.0
    assert nearest_surface(depth, 4)[0, 10, 14] == 980.0
    assert nearest_surface(depth, 4)[0, 0, 0] == 1000.0
    assert nearest_surface(torch.zeros(1, 5, 5), 2).eq(0).all()


def test_locate_reads_the_nearest_surface_in_its_window(monkeypatch):
    """A match two pixels beside a raised square lands on the table without a depth window and
    on the square's top with one."""
    frames = torch.zeros(1, 4, H, W)
    frames[:, 3] = 1000.0 * HEIGHT_M / DEPTH_SCALE_MM
    u, v = pixel(0.05, 0.05)
    frames[:, 3, v - 3 : v + 3, u - 3 : u + 3] = 1000.0 * (HEIGHT_M - TOP_M) / DEPTH_SCALE_MM
    beside = torch.tensor([[[u + 5.0, float(v)]]])  # two pixels right of the square's edge
    monkeypatch.setattr(modeling_localizer, "refined_pixels", lambda logits, stride: beside)
    queries = StageQueries(torch.randn(1, TINY.dim), torch.tensor([TOP_M]))
    for window, height in ((0, 0.0), (4, TOP_M)):
        localizer = camera_localizer(dataclasses.replace(TINY, depth_window=window))
        point = localizer.locate(frames, queries)
        assert point[0, 0, 2].item() == pytest.approx(height, abs=2e-3)


def test_a_target_off_the_seen_surface_is_placed_at_the_demonstrations_height(monkeypatch):
    """A stage that ends 10 cm above the table (a glass held over its coaster): its pixel's
    depth is the table's. With a height tolerance the point is where the pixel's ray crosses
    the demonstrations' height, 10 cm up; one whose depth agrees with that height keeps it."""
    frames = torch.zeros(1, 4, H, W)
    frames[:, 3] = 1000.0 * HEIGHT_M / DEPTH_SCALE_MM
    above = torch.tensor([[0.1, -0.05, 0.1]])  # in mid-air, above the table
    pixels = camera_localizer().project(above)[None]  # (1, 1, 2)
    monkeypatch.setattr(modeling_localizer, "refined_pixels", lambda logits, stride: pixels)
    for tolerance, expected in ((0.0, [0.1 / 0.9, -0.05 / 0.9, 0.0]), (0.03, above[0].tolist())):
        localizer = camera_localizer(dataclasses.replace(TINY, height_tolerance=tolerance))
        point = localizer.locate(frames, StageQueries(torch.randn(1, TINY.dim), above[:, 2]))
        assert torch.allclose(point[0, 0], torch.tensor(expected), atol=1e-4), tolerance
    on_table = StageQueries(torch.randn(1, TINY.dim), torch.tensor([0.02]))  # within 3 cm
    localizer = camera_localizer(dataclasses.replace(TINY, height_tolerance=0.03))
    assert localizer.locate(frames, on_table)[0, 0, 2].item() == pytest.approx(0.0, abs=1e-4)


def test_matching_cells_of_four_or_eight_pixels():
    """The map's cells are `stride` pixels a side; saved localizers (without the field) load
    with 8; any other stride, or a negative height tolerance, is refused."""
    for stride in (4, 8):
        localizer = camera_localizer(dataclasses.replace(TINY, stride=stride))
        assert localizer.map(torch.zeros(2, 4, H, W)).shape == (
            2,
            TINY.dim,
            H // stride,
            W // stride,
        )
    old = LocalizerConfig.from_dict({"width": 8, "dim": 8, "num_targets": 1, "depth_window": 4})
    assert (old.stride, old.height_tolerance) == (8, 0.0)
    with pytest.raises(ValueError, match="stride=6"):
        LocalizerConfig(stride=6)
    with pytest.raises(ValueError, match="height_tolerance=-0.1"):
        LocalizerConfig(height_tolerance=-0.1)


def test_stage_end_points_are_where_each_stage_ended():
    tcp = np.arange(8 * 3, dtype=np.float32).reshape(8, 3)
    stage = np.array([0, 0, 1, 1, 1, 2, 2])  # stage 1 done by step 2, stage 2 by step 5
    points = stage_end_points(torch.from_numpy(stage_subgoals(tcp, stage)), 2)
    assert torch.equal(points, torch.from_numpy(tcp[[3, 6]]))
    with pytest.raises(ValueError, match="showing 1 stage targets, 2 needed"):
        stage_end_points(torch.from_numpy(stage_subgoals(tcp, np.zeros(7))), 2)


def test_a_final_stage_ending_at_rest_is_still_a_stage_target():
    """Factory Packing's conveyor completes its last stage while the robot holds still: the
    final stage's target and the episode's rest are one point, and both stages are found."""
    tcp = np.arange(8 * 3, dtype=np.float32).reshape(8, 3)
    tcp[5:] = tcp[5]  # the robot rests from frame 5 on
    stage = np.array([0, 0, 1, 1, 1, 1, 2])  # stage 1 done by step 2, stage 2 by step 6
    points = stage_end_points(torch.from_numpy(stage_subgoals(tcp, stage)), 2)
    assert torch.equal(points, torch.from_numpy(tcp[[3, 7]]))


def test_an_episode_short_of_the_stages_is_refused_by_its_labels(collections):
    base, _ = collections
    demo = next(e for e in load_episodes(base) if e.role == "demo")
    assert stage_episode(demo, 1, "front").points.shape == (1, 3)
    with pytest.raises(ValueError, match="completes 1 stages, 2 needed"):
        stage_episode(demo, 2, "front")


def test_colour_jitter_recolours_rgb_and_keeps_depth():
    """Each sequence gets one recolouring: its RGB channels permuted and scaled (or made grey),
    the same on all its frames; depth untouched; strength 0 is the identity."""
    colour = torch.tensor([0.8, 0.4, 0.1])
    frames = torch.zeros(64, 3, 4, 8, 8)
    frames[:, :, :3] = colour.view(1, 1, 3, 1, 1)
    frames[:, :, 3] = torch.rand(64, 3, 8, 8)
    generator = torch.Generator().manual_seed(0)
    assert colour_jitter(frames, 0.0, generator) is frames
    out = colour_jitter(frames, 0.3, generator)
    assert torch.equal(out[:, :, 3], frames[:, :, 3])
    rgb = out[:, :, :3]
    assert torch.equal(rgb[:, :1].expand_as(rgb), rgb)  # one draw per sequence, every frame
    rgb = out[:, 0, :3, 0, 0]
    grey = (rgb[:, 0] == rgb[:, 1]) & (rgb[:, 1] == rgb[:, 2])
    assert 0 < grey.sum() < 64
    assert len(set(rgb[~grey].argmax(dim=1).tolist())) > 1  # the red channel moved
    for row in rgb[~grey]:  # each a permutation of the colour, scaled by gains in [0.7, 1.3]
        ratios = [
            row / colour[list(p)]
            for p in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))
        ]
        assert any(((r >= 0.7 - 1e-6) & (r <= 1.3 + 1e-6)).all() for r in ratios), row


@torch.no_grad()
def test_trained_localizer_finds_unseen_colours_from_the_demonstrations(
    localizer_path, collections
):
    """Trained on 8 base environments, it places novel targets (colours it never saw) from
    three demonstrations well inside the spread of the targets."""
    _, novel = collections
    localizer = load_localizer(localizer_path)
    assert localizer.config.num_targets == 1 and localizer.sha256
    log = torch.load(localizer_path, weights_only=True)["extra"]["log"]
    assert log[-1]["match_loss"] < 0.6 * log[0]["match_loss"], log
    errors, guesses = [], []
    for env in (0, 1, 2):
        demos = [e for e in load_episodes(novel, split="novel") if e.env_index == env]
        infos = [stage_episode(ref, 1, "front") for ref in demos]
        reader = EpisodeReader()
        firsts = torch.stack([reader.read(i.ref, np.array([0])).frames[0] for i in infos])
        points = torch.from_numpy(np.stack([i.points for i in infos])).float()
        for j in range(len(infos)):
            others = [k for k in range(len(infos)) if k != j]
            queries = localizer.queries(firsts[others], points[others])
            located = localizer.locate(firsts[j : j + 1], queries)[0, 0]
            errors.append(float(torch.linalg.norm(located[:2] - points[j, 0, :2])))
            guesses.append(float(torch.linalg.norm(points[j, 0, :2])))
    assert np.mean(errors) < 0.4 * np.mean(guesses), (errors, guesses)


def test_located_points_of_the_agent_episodes(localizer_path, collections):
    base, _ = collections
    episodes = load_episodes(base)
    localizer = load_localizer(localizer_path)
    located = located_points(localizer, episodes, num_demos=3)
    agents = [e for e in episodes if e.role == "agent_success"]
    assert sorted(located) == sorted((str(e.path), e.traj) for e in agents)
    targets = [stage_episode(e, 1, "front").points[0, :2] for e in agents]
    errors = [
        np.linalg.norm(located[str(e.path), e.traj][0, :2] - t)
        for e, t in zip(agents, targets, strict=True)
    ]
    guesses = [np.linalg.norm(t) for t in targets]  # the training mean's guess, the centre
    # in its training environments, well inside the spread (the margin holds across torch's
    # thread counts, whose float sums differ)
    assert np.median(errors) < 0.5 * np.median(guesses), (errors, guesses)


def test_localizer_training_resumes_to_the_same_weights(collections, tmp_path):
    base, _ = collections
    whole = train_localizer(localizer_config(base, tmp_path / "whole", epochs=2, updates=5), TINY)
    train_localizer(localizer_config(base, tmp_path / "split", epochs=1, updates=5), TINY)
    resumed = train_localizer(localizer_config(base, tmp_path / "split", epochs=2, updates=5), TINY)
    a, b = load_localizer(whole).state_dict(), load_localizer(resumed).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    same_shapes = "another demo_matching localizer config"  # the weights' shapes are alike
    with pytest.raises(ValueError, match=same_shapes):
        train_localizer(
            localizer_config(base, tmp_path / "split", epochs=3, updates=5),
            dataclasses.replace(TINY, stride=4),
        )
    with pytest.raises(ValueError, match="profile='paper'"):
        localizer_config(base, tmp_path / "x", profile="paper")


def policy_config(name: str, localizer: LocalizerConfig | None = TINY):
    tiny = {"dct": {"num_heads": 4, "ff_dim": 32}, "scan": {"lstm_hidden": 12, "attention_dim": 8}}
    visual = VisualHeadConfig(arch="small_cnn", out_dim=16, width=4, dropout=0.0)
    return POLICIES.preset(
        name, "mini", visual=visual, actor_hidden=(16, 8), frozen_encoder=False,
        localizer=localizer, **tiny.get(name, {}),
    )  # fmt: skip


def episode_batch(collection, env: int, role: str, n: int):
    refs = [e for e in load_episodes(collection) if e.env_index == env and e.role == role][:n]
    reader = EpisodeReader()
    return pad_sequences([reader.read(r) for r in refs])


@pytest.mark.parametrize("name", ["naive_dc", "dct", "scan"])
def test_online_actions_equal_batched_with_a_localizer(name, collections):
    """The policy locates its targets in the rollout's first frame, online and batched alike,
    and a batch given those points (`located`, as training caches them) acts the same."""
    base, _ = collections
    torch.manual_seed(0)
    policy = make_policy(name, policy_config(name))
    policy.localizer.set_camera(torch.from_numpy(INTRINSIC), torch.from_numpy(EXTRINSIC))
    policy.set_action_stats(torch.randn(50, 4) * 0.2)
    with torch.no_grad():  # the pointer head's paths, which start at 0, open
        policy.subgoal_gain.fill_(0.5)
        policy.subgoal_head.residual.weight.normal_(0, 0.1)
    policy.eval()
    demos = episode_batch(base, 0, "demo", 3)
    rollout = episode_batch(base, 0, "agent_success", 1)
    with torch.no_grad():
        out = policy(rollout, demos)
        points = policy.localizer.locate(rollout["frames"][:, 0], policy.demo_queries(demos))
        located = points.flatten(1)[:, None].expand(-1, rollout["mask"].shape[1], -1)
        given = policy({**rollout, "located": located}, demos)
    assert torch.allclose(out["pos_chunk"], given["pos_chunk"])
    assert torch.allclose(out["grip_chunk"], given["grip_chunk"])
    expected = policy.to_action(*policy.ensemble_chunks(out["pos_chunk"], out["grip_chunk"]))[0]
    policy.reset(demos)
    for t in range(int(rollout["lengths"][0])):
        action = policy.act(rollout["frames"][0, t], proprio=rollout["proprio"][0, t])
        assert np.allclose(action, expected[t].numpy(), atol=1e-4), t
    with pytest.raises(ValueError, match="rollouts\\['located'\\] of shape"):
        policy({**rollout, "located": located[..., :2]}, demos)
    with pytest.raises(ValueError, match="demos\\['subgoal'\\]"):
        policy.reset({k: v for k, v in demos.items() if k != "subgoal"})


def test_policies_train_reading_a_frozen_localizer(localizer_path, collections, tmp_path):
    base, _ = collections
    cfg = TrainPolicyConfig.from_preset(
        "PressButton", "naive_dc", "mini", data=base, out=tmp_path / "policy",
        localizer=localizer_path, epochs=2, progress=False, num_envs=0, composition=(2, 2),
        feature_dropout=0.0,  # end to end: no cached features
    )  # fmt: skip
    policy = load_policy(train_policy(cfg, policy_config("naive_dc", LocalizerConfig())))
    localizer = load_localizer(localizer_path)
    assert policy.config.localizer == localizer.config  # the checkpoint's sizes, not the preset's
    a, b = policy.localizer.state_dict(), localizer.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    extra = torch.load(cfg.out / "policy.pt", weights_only=True)["extra"]
    assert extra["localizer_sha256"] == localizer.sha256
    diagnosis = load_script("rollout_localization").main(  # the base episodes as its "rollouts"
        load_script("rollout_localization").Config(
            policy=cfg.out / "policy.pt", rollouts=base, demos=base, num_demos=3
        )
    )
    found, missed = diagnosis["found"], diagnosis["missed"]
    assert found["rollouts"] + missed["rollouts"] == diagnosis["rollouts"] == 48
    assert found["successes"] + missed["successes"] == 48  # every synthetic episode succeeds
    bins = diagnosis["by_located_error_cm"]
    assert sum(b["rollouts"] for b in bins.values()) == 48
    per_rollout = diagnosis["per_rollout"]
    assert len(per_rollout) == 48 and all(r["success"] for r in per_rollout)
    assert all(np.isfinite(r["aimed_at_closest_cm"]) for r in per_rollout)  # it has the head
    assert sum(r["located_cm"] < 3 for r in per_rollout) == found["rollouts"]
    # the synthetic episodes never command the gripper closed
    assert diagnosis["first_close"] == {
        "rollouts": 0, "median_cm": None, "within_2cm": 0, "median_abs_cm": {"x": None, "y": None},
        "median_height_cm": None, "median_step": None,
    }  # fmt: skip
    assert diagnosis["expert_first_close"] == {
        "episodes": 8 * 3, "closed": 0, "median_cm": None, "median_height_cm": None,
        "median_step": None,
    }  # fmt: skip
    own = diagnosis["own_first_close"]  # the policy's own gripper output on those frames
    assert own["episodes"] == 48 and 0 <= own["closed"] <= 48
    assert own["median_steps_before_recorded"] is None  # the recorded episodes never close
    assert all(r["first_close_cm"] is None for r in per_rollout)
    gain = diagnosis["follow_gain"]
    assert (gain["shift_cm"], gain["steps"], gain["actions"]) == (5.0, 30, "online")
    assert all(isinstance(gain[axis], float) and np.isfinite(gain[axis]) for axis in "xy"), gain
    # an actor that reads neither the located points nor the pointer head's offset does not
    # follow them at all
    checkpoint = torch.load(cfg.out / "policy.pt", weights_only=True)
    state, start = checkpoint["state_dict"], policy.history_dim + policy.task_dim
    state["actor.body.0.weight"][:, start:] = 0  # the offsets, then the predicted one
    state["subgoal_gain"].zero_()
    torch.save(checkpoint, tmp_path / "blind.pt")
    blind = load_script("rollout_localization").main(
        load_script("rollout_localization").Config(
            policy=tmp_path / "blind.pt", rollouts=base, demos=base, num_demos=3
        )
    )
    assert blind["follow_gain"]["x"] == blind["follow_gain"]["y"] == 0.0
    missing = dataclasses.replace(cfg, out=tmp_path / "x", localizer=tmp_path / "missing.pt")
    with pytest.raises(FileNotFoundError, match="aed train-localizer"):
        train_policy(missing, policy_config("naive_dc"))


def test_first_close_is_the_first_closed_command_and_the_tcp_offset_there():
    script = load_script("rollout_localization")
    first_close = script.first_close
    tcp = np.array([[0.0, 0.0, 0.3], [0.1, 0.0, 0.2], [0.2, 0.0, 0.1], [0.2, 0.0, 0.1]])
    actions = np.array([[0, 0, 0, 1.0], [0, 0, 0, -1.0], [0, 0, 0, -1.0]])
    step, offset = first_close(np.array([0.2, 0.0, 0.05]), tcp, actions)
    assert step == 1 and np.allclose(offset, [-0.1, 0.0, 0.15])
    assert first_close(np.zeros(3), tcp, np.abs(actions)) is None
    late = (3, np.array([0.0, 0.0, 0.004]))
    early = (1, np.array([0.03, 0.04, 0.06]))
    own = script.own_first_close([late, late, None], [early, None, early])
    assert own["episodes"] == 3 and own["closed"] == 2 and own["median_cm"] == pytest.approx(5.0)
    assert own["median_height_cm"] == pytest.approx(6.0) and own["median_step"] == 1.0
    assert own["median_steps_before_recorded"] == 2.0  # only the first episode has both
    refs = [SimpleNamespace(env_index=e) for e in (0, 1, 0, 0, 1, 2)]
    assert script.first_per_env(refs, 2) == [refs[i] for i in (0, 1, 2, 4, 5)]


def test_the_follow_gain_sums_the_actions_taken_online():
    """The response is of the temporal ensemble `act` takes, not of each chunk's first action."""

    script = load_script("rollout_localization")

    class Run(script.PolicyRun):  # the script's own `online_actions`, a scripted policy
        def __init__(self) -> None:
            self.policy = SimpleNamespace(
                action_std=torch.full((4,), 2.0), ensemble_chunks=DCPolicy.ensemble_chunks
            )

        def __call__(self, points: torch.Tensor) -> dict:
            chunk = torch.zeros(1, 4, 3, 3)  # (B, T, chunk, xyz): the first actions never move
            chunk[..., 1:, :2] = points[0, 0, :2]  # the later ones follow the located point
            return {"pos": chunk[:, :, 0], "pos_chunk": chunk, "grip_chunk": chunk[..., :1]}

    run, points = Run(), torch.zeros(1, 2, 3)
    response = script.action_response(run, run(points), points, 0.5, 4)
    online, _ = run.online_actions(run(points + 0.5))
    assert torch.all(online[0, 1:, :2] > 0)  # from step 1 on, later chunks' actions are averaged
    expected = float(2.0 * online[0, :4, 0].sum())
    assert response[0] == pytest.approx(expected) and response[0] > 0


def test_the_probe_script_measures_novel_errors(localizer_path, collections, tmp_path):
    probe = load_script("demo_localizer")
    base, novel = collections
    config = probe.Config(localizer=localizer_path, novel=novel, data=base, out=tmp_path / "r.json")
    result = probe.main(config)
    errors = result["novel_demo_xy_error_cm"]
    assert errors["localizer"]["n"] == errors["mean_guess"]["n"] == 12
    low, high = errors["localizer"]["mean_95"]
    assert low <= errors["localizer"]["mean"] <= high
    assert errors["localizer"]["mean"] < 0.5 * errors["mean_guess"]["mean"], errors
    assert json.loads((tmp_path / "r.json").read_text()) == result
    every = probe.main(dataclasses.replace(config, every=2, out=None))["novel_demo_xy_error_cm"]
    assert every["localizer"]["n"] == 3 * (3 + 4 + 4 + 5)  # demonstrations of 6 to 9 frames

"""Training data: per-iteration compositions, frame tensors, labels, padding, determinism.

Runs on small synthetic shards written with `aed_tasks.trajectory` (no simulation): every
frame's pixels encode its index in the episode, so alignment can be checked exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from aed_models.augment import RolloutAugment
from aed_models.data import (
    DEPTH_SCALE_MM,
    EnvironmentIterations,
    EnvironmentSampler,
    EpisodeDataset,
    collate_episodes,
    load_episodes,
    to_frames,
)
from aed_tasks import trajectory
from aed_tasks.episode import Episode
from tests.helpers import recorded_episode, write_synthetic_collection

H, W = 120, 160
ONSET = 9


def synthetic(
    role: str, env_index: int, seed: int, steps: int
) -> tuple[Episode, trajectory.RecordedSteps]:
    """An episode whose frame t has red = t, green = 100 + env_index, depth = 10 * t mm, and
    whose TCP x is t mm (fingers at 0.04 m)."""
    t = np.arange(steps + 1)
    rgb = np.zeros((steps + 1, H, W, 3), np.uint8)
    rgb[..., 0] = t[:, None, None]
    rgb[..., 1] = 100 + env_index
    depth = (10 * t[:, None, None, None] * np.ones((1, H, W, 1))).astype(np.int16)
    tcp_pose = np.stack([t / 1000, 0 * t, 0 * t + 0.2, 1 + 0 * t, 0 * t, 0 * t, 0 * t], 1)
    actions = np.tile(np.arange(steps, dtype=np.float32)[:, None], (1, 4))
    onset = ONSET if role == "agent_failure" else None
    return recorded_episode(
        "PickPlace", role, env_index, seed, rgb, depth, actions, tcp_pose, onset=onset
    )


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> Path:
    """Two environments; per env 3 demos, 4 successes, 2 failures of lengths 15..24."""
    counts = {"demo": 3, "agent_success": 4, "agent_failure": 2}
    return write_synthetic_collection(
        tmp_path_factory.mktemp("synthetic"), counts, steps=15, step_increment=3
    )


def test_composition_shapes_and_roles(collection):
    data = EnvironmentIterations(load_episodes(collection), "detector")
    assert len(data) == 2
    batch = data[0]
    demos, rollouts = batch["demos"], batch["rollouts"]
    assert demos["frames"].shape[:1] == (5,) and rollouts["frames"].shape[:1] == (20,)
    assert demos["frames"].shape[2:] == (4, H, W) and demos["frames"].dtype == torch.float32
    assert rollouts["is_failure"].sum() == 10 and not rollouts["is_failure"][:10].any()
    green = rollouts["frames"][:, 0, 1, 0, 0] * 255
    assert torch.allclose(
        green, torch.full_like(green, 100 + batch["env_index"])
    )  # one environment


def test_frames_labels_actions_align_and_pad(collection):
    batch = EnvironmentIterations(load_episodes(collection), "detector", seed=3)[1]
    r = batch["rollouts"]
    for i, n in enumerate(r["lengths"].tolist()):
        source = torch.round(r["frames"][i, :n, 0, 0, 0] * 255).long()
        assert torch.equal(source, torch.arange(n))  # unaugmented: every frame, in order
        assert torch.allclose(r["frames"][i, :n, 3, 0, 0], source * 10 / DEPTH_SCALE_MM)
        expected = (source - 1 >= ONSET).float() if r["is_failure"][i] else torch.zeros(n)
        assert torch.equal(
            r["labels"][i, :n], expected
        )  # successes all 0; failures switch at onset + 1
        assert torch.equal(r["actions"][i, : n - 1, 0], source[: n - 1].float())
        assert torch.equal(
            torch.round(r["proprio"][i, :n, 0] * 1000).long(), source
        )  # TCP x = t mm
        assert torch.allclose(r["proprio"][i, :n, 3:], torch.tensor(0.04))  # finger joints
        assert r["mask"][i, :n].all() and not r["mask"][i, n:].any()
        assert (r["frames"][i, n:] == 0).all() and (r["labels"][i, n:] == 0).all()


def test_action_chunks_are_the_episodes_next_actions_from_each_read_frame(collection):
    """Action t of the synthetic episodes is t: a frame's chunk is (t, t + 1, t + 2), also
    when the frames read skip those steps, and ends with the episode's actions."""
    episodes = load_episodes(collection)
    for max_frames, frames in ((6, "random"), (None, "even")):
        data = EnvironmentIterations(
            episodes, "detector", max_frames=max_frames, rollout_frames=frames, action_chunk=3
        )
        batch = data[(1, 1)]
        r = batch["rollouts"]
        assert r["action_chunks"].shape == (*r["mask"].shape, 3, 4)
        assert "action_chunks" not in batch["demos"]
        assert not r["chunk_valid"][~r["mask"]].any()
        for i, n in enumerate(r["lengths"].tolist()):
            source = torch.round(r["frames"][i, :n, 0, 0, 0] * 255).long()
            later = source[:, None] + torch.arange(3)[None]
            valid = r["chunk_valid"][i, :n]
            assert torch.equal(r["action_chunks"][i, :n, :, 0][valid], later[valid].float())
            assert (r["action_chunks"][i, :n][~valid] == 0).all()
            if max_frames is None:  # every frame: the episode has T = n - 1 actions
                assert torch.equal(valid, later < n - 1)
    with pytest.raises(ValueError, match="action_chunk=0: must be >= 1"):
        EnvironmentIterations(episodes, "detector", action_chunk=0)


def test_augmentation_keeps_alignment_and_skips_demos(collection):
    data = EnvironmentIterations(
        load_episodes(collection), "detector", augment=RolloutAugment(), seed=1
    )
    batch = data[(2, 0)]
    r = batch["rollouts"]
    changed = 0
    for i, n in enumerate(r["lengths"].tolist()):
        source = torch.round(r["frames"][i, :n, 0, 0, 0] * 255).long()
        changed += not torch.equal(source, torch.arange(n))
        assert torch.equal(torch.round(r["proprio"][i, :n, 0] * 1000).long(), source)
        expected = (source - 1 >= ONSET).float() if r["is_failure"][i] else torch.zeros(n)
        assert torch.equal(r["labels"][i, :n], expected)
    assert changed > 10
    d = batch["demos"]
    for i, n in enumerate(d["lengths"].tolist()):
        assert torch.equal(torch.round(d["frames"][i, :n, 0, 0, 0] * 255).long(), torch.arange(n))


def test_compositions_and_replacement(collection):
    refs = load_episodes(collection)
    policy = EnvironmentIterations(refs, "policy")[0]
    assert policy["demos"]["frames"].shape[0] == 5 and policy["rollouts"]["frames"].shape[0] == 10
    assert not policy["rollouts"]["is_failure"].any()
    svdd = EnvironmentIterations(refs, "svdd")[0]
    assert svdd["rollouts"]["frames"].shape[0] == 20  # 4 successes drawn with replacement
    capped = EnvironmentIterations(refs, "policy", max_frames=8)[0]
    assert capped["rollouts"]["frames"].shape[1] == 8
    with pytest.raises(ValueError, match="composition='nope'"):
        EnvironmentIterations(refs, "nope")
    no_failures = [e for e in refs if e.role != "agent_failure"]
    with pytest.raises(ValueError, match="no agent_failure episodes"):
        EnvironmentIterations(no_failures, "detector")


def test_deterministic_with_workers_and_epochs(collection):
    data = EnvironmentIterations(
        load_episodes(collection), "detector", augment=RolloutAugment(), max_frames=12, seed=5
    )
    sampler = EnvironmentSampler(len(data), epochs=2, seed=5)
    order = list(sampler)
    assert sorted(order[:2]) == [(0, 0), (0, 1)] and sorted(order[2:]) == [(1, 0), (1, 1)]
    serial = list(DataLoader(data, sampler=sampler, batch_size=None, num_workers=0))
    parallel = list(DataLoader(data, sampler=sampler, batch_size=None, num_workers=2))
    for a, b in zip(serial, parallel, strict=True):
        assert a["env_index"] == b["env_index"]
        assert torch.equal(a["rollouts"]["frames"], b["rollouts"]["frames"])
        assert torch.equal(a["rollouts"]["labels"], b["rollouts"]["labels"])
    assert not torch.equal(serial[0]["rollouts"]["lengths"], serial[2]["rollouts"]["lengths"]) or (
        serial[0]["env_index"] != serial[2]["env_index"]
    )  # a new epoch draws anew


def test_episode_dataset_and_frame_normalisation(collection):
    refs = load_episodes(collection)
    loader = DataLoader(EpisodeDataset(refs), batch_size=4, collate_fn=collate_episodes)
    batch = next(iter(loader))
    assert batch["frames"].shape[0] == 4 and len(batch["refs"]) == 4
    rgb = np.full((1, 2, 2, 3), 255, np.uint8)
    depth = np.array([0, 2500, 5000, 9000], np.int16).reshape(1, 2, 2, 1)
    frames = to_frames(rgb, depth)
    assert frames.shape == (1, 4, 2, 2) and torch.all(frames[:, :3] == 1.0)
    assert torch.allclose(frames[0, 3].flatten(), torch.tensor([0.0, 0.5, 1.0, 1.0]))

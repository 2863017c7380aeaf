"""Rollout augmentation: aligned frames and labels, seeded, switchable, paper's probabilities."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aed_models.augment import RolloutAugment


def test_disabled_is_identity():
    frames, labels = np.arange(50), (np.arange(50) >= 20).astype(np.uint8)
    out_frames, out_labels = RolloutAugment(enabled=False)(frames, labels, rng=0)
    assert np.array_equal(out_frames, frames) and np.array_equal(out_labels, labels)


def test_seeded_and_varied():
    augment = RolloutAugment()
    assert np.array_equal(augment.indices(200, 7), augment.indices(200, 7))
    assert not np.array_equal(augment.indices(200, 7), augment.indices(200, 8))
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    assert np.array_equal(augment.indices(80, rng_a), augment.indices(80, rng_b))


@pytest.mark.parametrize("seed", range(5))
def test_frames_and_labels_stay_aligned(seed):
    length, onset = 120, 70
    frames = np.arange(length)[:, None, None] * np.ones((1, 2, 2))  # each frame shows its index
    labels = (np.arange(length) >= onset).astype(np.uint8)
    actions = np.arange(length, dtype=np.float32)[:, None].repeat(4, axis=1)
    out_frames, out_labels, out_actions = RolloutAugment()(frames, labels, actions, rng=seed)
    source = out_frames[:, 0, 0].astype(int)
    assert np.array_equal(out_labels, (source >= onset).astype(np.uint8))
    assert np.array_equal(out_actions[:, 0].astype(int), source)
    assert len(out_frames) == len(out_labels) == len(out_actions) > 0
    assert source.min() >= 0 and source.max() < length


def test_operations_follow_the_probabilities():
    """Draws are keep / drop / swap / copy at 0.3 / 0.3 / 0.2 / 0.2; a swap covers two frames,
    so per frame: 0.3 / 1.2 = 25% dropped, 0.2 / 1.2 = 16.7% copied, 33.3% swapped."""
    idx = RolloutAugment().indices(20000, 0)
    counts = np.bincount(idx, minlength=20000)
    assert 0.23 < np.mean(counts == 0) < 0.27
    assert 0.15 < np.mean(counts == 2) < 0.19
    assert counts.max() <= 2
    backwards = np.flatnonzero(np.diff(idx) < 0)
    assert 0.15 < len(backwards) / 20000 * 1.2 < 0.25  # one backward step per swap draw
    assert np.all(idx[backwards] == idx[backwards + 1] + 1)  # a swap exchanges neighbours


def test_torch_tensors_and_short_sequences():
    augment = RolloutAugment()
    frames = torch.arange(30).float()
    (out,) = augment(frames, rng=1)
    assert isinstance(out, torch.Tensor) and torch.equal(
        out, frames[torch.as_tensor(augment.indices(30, 1))]
    )
    assert len(augment.indices(1, 0)) >= 1  # never empty
    assert len(augment.indices(0, 0)) == 0


def test_invalid_probabilities_are_named():
    with pytest.raises(ValueError, match="must be 1"):
        RolloutAugment(p_keep=0.5)
    with pytest.raises(ValueError, match="p_drop=-0.1"):
        RolloutAugment(p_keep=0.7, p_drop=-0.1)
    with pytest.raises(ValueError, match="different lengths"):
        RolloutAugment()(np.zeros(5), np.zeros(6), rng=0)

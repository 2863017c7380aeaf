"""Detector objectives against values computed by hand on small tensors."""

from __future__ import annotations

import math

import pytest
import torch

from aed_models.losses import (
    Triplets,
    masked_bce,
    pattern_l1,
    sample_triplets,
    temporal_triplet_loss,
)


def test_pattern_l1_is_mean_abs_over_valid_frames():
    patterns = torch.tensor([[[1.0, -2.0], [3.0, 0.0], [100.0, 100.0]]])  # last frame is padding
    mask = torch.tensor([[True, True, False]])
    assert pattern_l1(patterns, mask).item() == pytest.approx((1 + 2 + 3 + 0) / 4)


def test_masked_bce_ignores_padding():
    logits = torch.tensor([[0.0, 2.0, 50.0]])
    labels = torch.tensor([[1.0, 0.0, 0.0]])
    mask = torch.tensor([[True, True, False]])
    expected = (math.log(2.0) + math.log(1.0 + math.exp(2.0))) / 2
    assert masked_bce(logits, labels, mask).item() == pytest.approx(expected, rel=1e-6)


def test_temporal_triplet_loss_matches_hand_computation():
    # one rollout of 10 frames; 1-d embeddings equal to the frame's value below
    emb = torch.tensor([0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0])[None, :, None]
    triplets = Triplets(
        torch.tensor([0, 0]), torch.tensor([0, 2]), torch.tensor([1, 0]), torch.tensor([6, 9])
    )
    lengths = torch.tensor([10])
    loss = temporal_triplet_loss(emb, triplets, lengths, margin=1.0, alpha=0.5, clip=0.5)
    # triplet 1: d_ap = 0.1/0.5 = 0.2, d_an = min(0.6, 0.5)/0.5 = 1
    #   -> m_t = 1 (1 - 0.5 (0.2 - 1)) = 1.4
    #   |0 - 0.5| - |0 - 3| + 1.4 = -1.1 -> 0
    # triplet 2: d_ap = 0.2/0.5 = 0.4, d_an = min(0.7, 0.5)/0.5 = 1 -> m_t = 1.3
    #   |1 - 0| - |1 - 0| + 1.3 = 1.3
    assert loss.item() == pytest.approx((0.0 + 1.3) / 2, rel=1e-6)


def test_temporal_triplet_loss_without_triplets_is_zero_with_grad():
    emb = torch.randn(2, 4, 3, requires_grad=True)
    empty = torch.zeros(0, dtype=torch.int64)
    loss = temporal_triplet_loss(emb, Triplets(empty, empty, empty, empty), torch.tensor([4, 4]))
    loss.backward()
    assert loss.item() == 0.0 and emb.grad is not None


def test_sampled_triplets_respect_labels_and_failures():
    labels = torch.tensor(
        [[0, 0, 0, 0, 0, 0], [0, 0, 0, 1, 1, 0], [0, 0, 0, 0, 0, 0]], dtype=torch.float32
    )
    mask = torch.tensor([[True] * 6, [True] * 5 + [False], [True] * 6])
    is_failure = torch.tensor([False, True, True])  # rollout 2 "failed" but kept no error frame
    t = sample_triplets(
        labels, mask, is_failure, per_rollout=50, generator=torch.Generator().manual_seed(0)
    )
    assert len(t.rollout) > 0 and (t.rollout == 1).all()
    lab = labels[1]
    assert (lab[t.anchor] == lab[t.positive]).all() and (lab[t.anchor] != lab[t.negative]).all()
    assert (t.anchor != t.positive).all()
    assert mask[1][t.positive].all() and mask[1][t.negative].all()

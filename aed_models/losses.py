"""Objectives of the error detectors (paper, "PrObe" and appendix "PrObe Details").

- `masked_bce`: L_cls, binary cross-entropy on per-frame error labels, padding left out.
- `pattern_l1`: L_pat, the L1 norm of PrObe's pattern features (sparsity).
- `sample_triplets` + `temporal_triplet_loss`: L_tem, a triplet loss on the logit embeddings
  of failed rollouts whose margin depends on how far apart in time the three frames are.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F


def masked_bce(logits: torch.Tensor, labels: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """L_cls: mean BCE over the valid frames, from logits (numerically safer than probabilities).

    Args:
        logits: (B, T) pre-sigmoid error scores.
        labels: (B, T) 0 normal / 1 error.
        mask: (B, T) True on real frames.
    """
    if logits.shape != labels.shape or logits.shape != mask.shape:
        raise ValueError(
            f"logits {tuple(logits.shape)}, labels {tuple(labels.shape)}, "
            f"mask {tuple(mask.shape)}: must match"
        )
    mask = mask.bool()
    if not mask.any():
        raise ValueError("mask selects no frame: nothing to classify")
    return F.binary_cross_entropy_with_logits(logits[mask], labels[mask].to(logits.dtype))


def pattern_l1(patterns: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """L_pat: mean |f_p| over the valid frames and the feature cells.

    The paper writes (1 / N_r T_h) sum |f_p|; we also average over the D cells so that the
    weight lambda_pat does not depend on the feature size. Since f_p is instance-normalised
    (unit variance per frame), a lower L1 means a sparser, peakier pattern.

    Args:
        patterns: (B, T, D).
        mask: (B, T) True on real frames.
    """
    if patterns.shape[:2] != mask.shape:
        raise ValueError(
            f"patterns {tuple(patterns.shape)} and mask {tuple(mask.shape)}: (B, T) must match"
        )
    mask = mask.bool()
    if not mask.any():
        raise ValueError("mask selects no frame")
    return patterns[mask].abs().mean()


class Triplets(NamedTuple):
    """Index tensors (N,) of sampled triplets: rollout, anchor / positive / negative time steps."""

    rollout: torch.Tensor
    anchor: torch.Tensor
    positive: torch.Tensor
    negative: torch.Tensor


def sample_triplets(
    labels: torch.Tensor,
    mask: torch.Tensor,
    is_failure: torch.Tensor,
    per_rollout: int,
    generator: torch.Generator | None = None,
) -> Triplets:
    """Anchors, positives and negatives drawn inside each failed rollout.

    For an anchor frame, a positive is another frame with the same label (normal or error),
    a negative a frame with the other label. Rollouts whose valid frames carry a single label
    (no error happened within the frames kept) give no triplet. Draws are uniform.

    Args:
        labels: (B, T) per-frame 0/1.
        mask: (B, T) True on real frames.
        is_failure: (B,) which rollouts failed.
        per_rollout: anchors per failed rollout.
    """
    if per_rollout < 1:
        raise ValueError(f"per_rollout={per_rollout}: must be >= 1")
    out: list[list[torch.Tensor]] = [[], [], [], []]
    for b in torch.nonzero(is_failure.bool()).flatten().tolist():
        valid = mask[b].bool()
        error = (labels[b] > 0.5) & valid
        normal = (labels[b] <= 0.5) & valid
        if error.sum() < 1 or normal.sum() < 1 or valid.sum() < 3:
            continue
        anchors = torch.multinomial(
            valid.float(), per_rollout, replacement=True, generator=generator
        )
        same = torch.where(error[anchors, None], error[None], normal[None]).float()  # (n, T)
        same[torch.arange(per_rollout, device=labels.device), anchors] = (
            0.0  # a positive is another frame
        )
        other = torch.where(error[anchors, None], normal[None], error[None]).float()
        usable = same.sum(1) > 0
        if not usable.any():
            continue
        anchors, same, other = anchors[usable], same[usable], other[usable]
        out[0].append(torch.full_like(anchors, b))
        out[1].append(anchors)
        out[2].append(torch.multinomial(same, 1, generator=generator).squeeze(1))
        out[3].append(torch.multinomial(other, 1, generator=generator).squeeze(1))
    if not out[0]:
        empty = torch.zeros(0, dtype=torch.int64, device=labels.device)
        return Triplets(empty, empty, empty, empty)
    return Triplets(*(torch.cat(parts) for parts in out))


def temporal_triplet_loss(
    embeddings: torch.Tensor,
    triplets: Triplets,
    lengths: torch.Tensor,
    margin: float = 1.0,
    alpha: float = 0.5,
    clip: float = 0.5,
) -> torch.Tensor:
    """L_tem = mean_i max(||a_i - p_i|| - ||a_i - n_i|| + m_t, 0),
    m_t = m (1 - alpha (d_ap - d_an)).

    d_ap, d_an are temporal distances normalised by the rollout's length (so they do not
    depend on how many frames were kept), clipped at `clip` and divided by it: they lie in
    [0, 1], and m_t in [m (1 - alpha), m (1 + alpha)]. A temporally close positive and a
    distant negative raise the margin (pull harder); a positive far in time lowers it.
    Returns 0 (with a gradient path) when there is no triplet.

    Args:
        embeddings: (B, T, E) logit embeddings.
        triplets: from `sample_triplets`.
        lengths: (B,) valid frames per rollout.
    """
    if clip <= 0:
        raise ValueError(f"clip={clip}: must be > 0")
    if len(triplets.rollout) == 0:
        return embeddings.sum() * 0.0
    b = triplets.rollout
    anchor = embeddings[b, triplets.anchor]
    positive = embeddings[b, triplets.positive]
    negative = embeddings[b, triplets.negative]
    length = lengths[b].to(embeddings.dtype).clamp(min=1.0)

    def temporal(i: torch.Tensor, j: torch.Tensor) -> torch.Tensor:
        return ((i - j).abs().to(embeddings.dtype) / length).clamp(max=clip) / clip

    d_ap = temporal(triplets.anchor, triplets.positive)
    d_an = temporal(triplets.anchor, triplets.negative)
    m_t = margin * (1.0 - alpha * (d_ap - d_an))
    gap = (anchor - positive).norm(dim=-1) - (anchor - negative).norm(dim=-1) + m_t
    return gap.clamp(min=0.0).mean()

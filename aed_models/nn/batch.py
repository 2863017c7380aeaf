"""Checks of the padded batches models read, with one set of rules and messages for all."""

from __future__ import annotations

from typing import Any

import torch

FRAMES = "'frames' (B, L, 4, H, W)"


def check_sequences(
    batch: Any, what: str, features: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """(inputs, mask (B, L)) of a padded group, mask all-True when absent. The inputs are its
    `frames` (B, L, 4, H, W) or, where `features` allows, its cached visual `features` (B, L, D)
    (a frozen head's)."""
    inputs = sequence_inputs(batch, what, features)
    return inputs, sequence_mask(batch, inputs, what)


def sequence_inputs(batch: Any, what: str, features: bool) -> torch.Tensor:
    """The group's `features` (B, L, D) when allowed and present, else its `frames`."""
    use_features = features and isinstance(batch, dict) and "features" in batch
    if not isinstance(batch, dict) or not (use_features or "frames" in batch):
        wanted = FRAMES + (" or 'features' (B, L, D)" if features else "")
        raise ValueError(f"{what}: expected a dict with {wanted}, and 'mask' (B, L)")
    if use_features:
        if batch["features"].dim() != 3:
            raise ValueError(
                f"{what}['features'] of shape {tuple(batch['features'].shape)}: expected (B, L, D)"
            )
        return batch["features"]
    frames = batch["frames"]
    if frames.dim() != 5 or frames.shape[2] != 4:
        raise ValueError(
            f"{what}['frames'] of shape {tuple(frames.shape)}: expected (B, L, 4, H, W)"
        )
    return frames


def sequence_mask(batch: dict, inputs: torch.Tensor, what: str) -> torch.Tensor:
    """The batch's (B, L) mask as bool, all-True when absent; every sequence starts valid."""
    mask = batch.get("mask")
    shape = inputs.shape[:2]
    if mask is None:
        return torch.ones(shape, dtype=torch.bool, device=inputs.device)
    if mask.shape != shape:
        raise ValueError(f"{what}['mask'] of shape {tuple(mask.shape)}: expected {tuple(shape)}")
    mask = mask.bool()
    if not mask[:, 0].all():
        raise ValueError(f"{what}: every sequence needs at least one frame (mask[:, 0] all True)")
    return mask

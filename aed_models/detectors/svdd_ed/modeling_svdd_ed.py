"""SVDDED: deep one-class SVDD (Ruff et al. 2018) centred on the demonstrations.

Each frame is embedded by a visual head; the centre c is the mean embedding of the
environment's demonstration frames; the score of a frame is its distance to c. Training
pulls the frames of successful rollouts towards c (no failures seen).

Against the trivial collapse (every frame mapped to one point, distance 0 for all):

- no bias terms (Ruff et al.): every bias of the head (FC, conv, normalisation shifts) is set
  to 0 and frozen, so a constant output can only come from all-zero weights;
- the centre is a fixed target per iteration (detached), as Ruff et al. fix c;
- the distance is scale-free, ||z - c||^2 / (||c||^2 + eps): shrinking the embedding towards
  zero does not lower the loss;
- a variance floor (`SVDDEDConfig.variance_weight`): with a spatial-softmax head, zero
  convolutions give every frame the same keypoints, a constant embedding without any bias.
"""

from __future__ import annotations

from typing import Any

import torch

from aed_models.detectors.base import Batch, ErrorDetector, check_frame, demo_mask, rollout_mask
from aed_models.detectors.svdd_ed.configuration_svdd_ed import SVDDEDConfig


class SVDDED(ErrorDetector):
    name = "svdd_ed"
    requires_policy = False
    output = "distance"
    trains_on = "successes"

    def __init__(self, config: SVDDEDConfig | None = None):
        from aed_models.nn import build_visual_head

        config = config or SVDDEDConfig()
        super().__init__(config)
        self.encoder = build_visual_head(config.visual_head_config())
        for name, param in self.encoder.named_parameters():
            if name.endswith("bias"):
                param.data.zero_()
                param.requires_grad_(False)
        self._centre: torch.Tensor | None = None

    def centre(self, demos: Batch) -> torch.Tensor:
        """(D,) mean embedding of all valid demonstration frames."""
        from aed_models.nn import encode_frames

        frames, mask = demo_mask(demos, self.name)
        return encode_frames(self.encoder, frames, mask)[mask].mean(0)

    def distance(self, embeddings: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
        return (embeddings - centre).pow(2).sum(-1) / (centre.pow(2).sum() + self.config.eps)

    def loss(self, batch: Batch, policy_features: Any = None) -> tuple[torch.Tensor, dict[str, float]]:
        from aed_models.nn import encode_frames

        rollouts = batch["rollouts"]
        mask = rollout_mask(rollouts)
        if "is_failure" in rollouts:
            mask = mask & ~rollouts["is_failure"].bool()[:, None]
        if not mask.any():
            raise ValueError("svdd_ed trains on successes: the batch has no successful rollout frame")
        centre = self.centre(batch["demos"]).detach()
        embeddings = encode_frames(self.encoder, rollouts["frames"], mask)[mask]
        svdd = self.distance(embeddings, centre).mean()
        parts = {"svdd": float(svdd.detach())}
        loss = svdd
        if self.config.variance_weight > 0 and len(embeddings) > 1:
            floor = torch.relu(1.0 - torch.sqrt(embeddings.var(0) + 1e-4)).mean()
            loss = loss + self.config.variance_weight * floor
            parts["variance_floor"] = float(floor.detach())
        return loss, parts

    @torch.no_grad()
    def score(self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None) -> torch.Tensor:
        from aed_models.nn import encode_frames

        mask = rollout_mask(rollouts)
        embeddings = encode_frames(self.encoder, rollouts["frames"], mask)
        return self.distance(embeddings, self.centre(demos)) * mask

    @torch.no_grad()
    def reset(self, demos: Batch | None = None) -> None:
        self._centre = self.centre(demos)

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: Any = None) -> float:
        self._require_reset(self._centre)
        embedding = self.encoder(check_frame(frame, self.name))[0]
        return float(self.distance(embedding, self._centre))

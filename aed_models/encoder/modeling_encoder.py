"""The scene encoder: visual head -> features, and a linear read-out of where things are."""

from __future__ import annotations

import torch
from torch import nn

from aed_models.encoder.configuration_encoder import EncoderConfig
from aed_models.nn.encoders import build_visual_head


class SceneEncoder(nn.Module):
    """(N, 4, H, W) frames -> (features (N, out_dim), standardised scene state (N, D)).

    The read-out is linear, so the features must carry the positions themselves: what the
    policies' actors then read.
    """

    def __init__(self, config: EncoderConfig):
        super().__init__()
        if not config.state_names:
            raise ValueError("EncoderConfig.state_names is empty: nothing to read out")
        self.config = config
        self.visual = build_visual_head(config.visual)
        dim = len(config.state_names)
        self.state_head = nn.Linear(config.visual.out_dim, dim)
        self.register_buffer("state_mean", torch.zeros(dim))
        self.register_buffer("state_std", torch.ones(dim))
        self.sha256 = ""

    def set_state_stats(self, states: torch.Tensor) -> None:
        """Per-column mean and std (floored at 1 mm) of the training states (M, D), over the
        known (finite) entries."""
        known = torch.isfinite(states)
        count = known.sum(0).clamp_min(2)
        mean = torch.where(known, states, 0.0).sum(0) / count
        var = torch.where(known, (states - mean) ** 2, 0.0).sum(0) / (count - 1)
        self.state_mean.copy_(mean)
        self.state_std.copy_(var.sqrt().clamp_min(1e-3))

    def forward(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        features = self.visual(frames)
        return features, self.state_head(features)

    def predict_state(self, frames: torch.Tensor) -> torch.Tensor:
        """The scene state in metres (joint positions in their own units)."""
        return self.forward(frames)[1] * self.state_std + self.state_mean

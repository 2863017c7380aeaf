"""LSTMED: an LSTM over the rollout's frame features alone (no demonstrations).

It can learn when errors usually happen in the training tasks, but not compare the rollout
with the demonstrations. Online, the LSTM state is carried from step to step.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from aed_models.detectors.base import (
    Batch,
    ErrorDetector,
    check_frame,
    rollout_frames,
    rollout_mask,
)
from aed_models.detectors.lstm_ed.configuration_lstm_ed import LSTMEDConfig
from aed_models.losses import masked_bce
from aed_models.nn.mlp import mlp
from aed_models.nn.recurrent import lstm_step


class LSTMED(ErrorDetector):
    requires_policy = False
    output = "probability"
    trains_on = "both"

    def __init__(self, config: LSTMEDConfig | None = None):
        from aed_models.nn import build_visual_head

        config = config or LSTMEDConfig()
        super().__init__(config)
        self.encoder = build_visual_head(config.visual_head_config())
        self.lstm = nn.LSTM(
            config.feature_dim, config.hidden_dim, config.num_layers, batch_first=True
        )
        self.classifier = mlp([config.hidden_dim, config.head_dim], out_dim=1)
        self._state: tuple[torch.Tensor, torch.Tensor] | None = None
        self._started = False

    def _logits(self, rollouts: Batch) -> torch.Tensor:
        from aed_models.nn import encode_frames

        feats = encode_frames(self.encoder, *rollout_frames(rollouts))
        out, _ = self.lstm(feats)  # padding comes after the valid frames: it never reaches them
        return self.classifier(out).squeeze(-1)

    def loss(
        self, batch: Batch, policy_features: Any = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        rollouts = batch["rollouts"]
        loss = masked_bce(self._logits(rollouts), rollouts["labels"], rollout_mask(rollouts))
        return loss, {"cls": float(loss.detach())}

    @torch.no_grad()
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        return torch.sigmoid(self._logits(rollouts)) * rollout_mask(rollouts)

    def reset(self, demos: Batch | None = None) -> None:
        """LSTMED ignores demonstrations; this clears the LSTM state."""
        self._state = None
        self._started = True

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: Any = None) -> float:
        if not self._started:
            raise RuntimeError("lstm_ed: call reset() before step()")
        out, self._state = lstm_step(
            self.lstm, self.encoder(check_frame(frame, self.name)), self._state
        )
        return float(torch.sigmoid(self.classifier(out))[0, 0])

"""TaskEmbED: error probability of one frame given a NaiveDC-style task embedding.

Task embedding (NaiveDC, James et al. 2018): per demonstration, the features of its first
and last frames concatenated, averaged over the demonstrations. No temporal information: the
probability of a frame depends on that frame and the demonstrations only. Memoryless: the
protocol reads the running maximum of the probability (`aed_models.detectors.postprocess`).
"""

from __future__ import annotations

from typing import Any

import torch

from aed_models.detectors.base import (
    Batch,
    ErrorDetector,
    PreparedDemos,
    check_demos,
    check_frame,
    rollout_frames,
    rollout_mask,
)
from aed_models.detectors.taskemb_ed.configuration_taskemb_ed import TaskEmbEDConfig
from aed_models.losses import masked_bce
from aed_models.nn.mlp import mlp


class TaskEmbED(ErrorDetector):
    requires_policy = False
    output = "probability"
    trains_on = "both"
    memoryless = True

    def __init__(self, config: TaskEmbEDConfig | None = None):
        from aed_models.nn import build_visual_head

        config = config or TaskEmbEDConfig()
        super().__init__(config)
        self.encoder = build_visual_head(config.visual_head_config())
        self.classifier = mlp([3 * config.feature_dim, *config.hidden_dims], out_dim=1)
        self._task: torch.Tensor | None = None

    def task_embedding(self, demos: Batch) -> torch.Tensor:
        """(2 D,) mean over demonstrations of [first frame feature, last frame feature]."""
        frames, mask = check_demos(demos, self.name)
        n = frames.shape[0]
        last = mask.long().sum(1) - 1
        ends = torch.cat(
            [frames[:, 0], frames[torch.arange(n, device=frames.device), last]]
        )  # (2N, 4, H, W)
        feats = self.encoder(ends)
        return torch.cat([feats[:n], feats[n:]], dim=-1).mean(0)

    def read_demos(self, demos: Batch | None) -> torch.Tensor:
        return self.task_embedding(demos)

    def logits(self, frame_feats: torch.Tensor, task: torch.Tensor) -> torch.Tensor:
        task = task.expand(*frame_feats.shape[:-1], task.shape[-1])
        return self.classifier(torch.cat([frame_feats, task], dim=-1)).squeeze(-1)

    def _batch_logits(self, rollouts: Batch, demos: Batch | PreparedDemos) -> torch.Tensor:
        from aed_models.nn import encode_frames

        return self.logits(
            encode_frames(self.encoder, *rollout_frames(rollouts)), self.demo_context(demos)
        )

    def loss(
        self, batch: Batch, policy_features: Any = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        rollouts = batch["rollouts"]
        loss = masked_bce(
            self._batch_logits(rollouts, batch["demos"]), rollouts["labels"], rollout_mask(rollouts)
        )
        return loss, {"cls": float(loss.detach())}

    @torch.no_grad()
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        mask = rollout_mask(rollouts)
        return torch.sigmoid(self._batch_logits(rollouts, demos)) * mask

    @torch.no_grad()
    def reset(self, demos: Batch | None = None) -> None:
        self._task = self.demo_context(demos)

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: Any = None) -> float:
        self._require_reset(self._task)
        feats = self.encoder(check_frame(frame, self.name))
        return float(torch.sigmoid(self.logits(feats, self._task))[0])

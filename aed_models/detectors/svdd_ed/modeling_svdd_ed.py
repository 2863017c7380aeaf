"""SVDDED: deep one-class SVDD (Ruff et al. 2018) centred on the demonstrations.

A frame's score is the scale-free distance of its embedding to the demonstrations' centre,
which follows the demonstrations in time (`SVDDEDConfig.centre`); training pulls successful
frames towards it, no failure seen. Against the trivial collapse (every frame on one point):
no trainable biases (Ruff et al.), a detached centre per iteration, a scale-free distance and a
variance floor on the embeddings. Memoryless: the protocol reads the running maximum of the
distance (`aed_models.detectors.postprocess`).
"""

from __future__ import annotations

from typing import Any

import torch

from aed_models.detectors.base import (
    Batch,
    ErrorDetector,
    check_demos,
    check_frame,
    rollout_frames,
    steps_of,
)
from aed_models.detectors.svdd_ed.configuration_svdd_ed import SVDDEDConfig


class SVDDED(ErrorDetector):
    requires_policy = False
    output = "distance"
    trains_on = "successes"
    memoryless = True

    def __init__(self, config: SVDDEDConfig | None = None):
        from aed_models.nn import build_visual_head

        config = config or SVDDEDConfig()
        super().__init__(config)
        self.encoder = build_visual_head(config.visual_head_config())
        for name, param in self.encoder.named_parameters():
            if name.endswith("bias"):
                param.data.zero_()
                param.requires_grad_(False)
        self._centres: torch.Tensor | None = None
        self._t = 0

    def centres(self, demos: Batch) -> torch.Tensor:
        """(S, D) centres: row t is the centre of frame t (frames past S - 1 use the last row).

        `all`: one row, the mean of every valid demonstration frame. `aligned`: row t is the
        mean over the demonstrations of their embedding at step t, each held at its last frame
        once it has ended; a demonstration subsampled in training (`source`, the frames'
        indices in their episode) contributes its latest kept frame at or before t.
        """
        from aed_models.nn import encode_frames

        frames, mask = check_demos(demos, self.name)
        embeddings = encode_frames(self.encoder, frames, mask)
        if self.config.centre == "all":
            return embeddings[mask].mean(0, keepdim=True)
        source = torch.where(
            mask, steps_of(demos, mask), torch.iinfo(torch.int64).max
        )  # padding is never "at or before t"
        steps = torch.arange(int(source[mask].max()) + 1, device=mask.device)
        latest = (
            torch.searchsorted(
                source.contiguous(), steps.expand(len(source), -1).contiguous(), right=True
            )
            - 1
        )
        latest = latest.clamp(
            min=0
        )  # a demonstration's first kept frame stands for the steps before it
        picked = embeddings.gather(1, latest[..., None].expand(-1, -1, embeddings.shape[-1]))
        return picked.mean(0)

    def read_demos(self, demos: Batch | None) -> torch.Tensor:
        return self.centres(demos)

    def distance(
        self, embeddings: torch.Tensor, steps: torch.Tensor, centres: torch.Tensor
    ) -> torch.Tensor:
        """Scale-free squared distance of each embedding (..., D) at step `steps` (...) to its
        centre: the nearest of the centres of steps t - window .. t + window (`aligned`)."""
        last = len(centres) - 1
        offsets = torch.arange(-self.config.window, self.config.window + 1, device=steps.device)
        rows = (steps.clamp(max=last)[..., None] + offsets).clamp(0, last)  # (..., 2 * window + 1)
        squared = (embeddings[..., None, :] - centres[rows]).pow(2).sum(-1).amin(-1)
        return squared / (centres.pow(2).sum(-1).mean() + self.config.eps)

    def loss(
        self, batch: Batch, policy_features: Any = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        from aed_models.nn import encode_frames

        rollouts = batch["rollouts"]
        frames, mask = rollout_frames(rollouts)
        if "is_failure" in rollouts:
            mask = mask & ~rollouts["is_failure"].bool()[:, None]
        if not mask.any():
            raise ValueError(
                "svdd_ed trains on successes: the batch has no successful rollout frame"
            )
        with torch.no_grad():  # a fixed target per iteration, as Ruff et al. fix c
            centres = self.centres(batch["demos"])
        embeddings = encode_frames(self.encoder, frames, mask)[mask]
        svdd = self.distance(embeddings, steps_of(rollouts, mask)[mask], centres).mean()
        parts = {"svdd": float(svdd.detach())}
        loss = svdd
        if self.config.variance_weight > 0 and len(embeddings) > 1:
            floor = torch.relu(1.0 - torch.sqrt(embeddings.var(0) + 1e-4)).mean()
            loss = loss + self.config.variance_weight * floor
            parts["variance_floor"] = float(floor.detach())
        return loss, parts

    @torch.no_grad()
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        from aed_models.nn import encode_frames

        frames, mask = rollout_frames(rollouts)
        embeddings = encode_frames(self.encoder, frames, mask)
        centres = self.demo_context(demos)
        return self.distance(embeddings, steps_of(rollouts, mask), centres) * mask

    @torch.no_grad()
    def embed(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        """(B, T, D) the encoder's embeddings, whose distances to the centres are the scores."""
        from aed_models.nn import encode_frames

        return encode_frames(self.encoder, *rollout_frames(rollouts))

    @torch.no_grad()
    def reset(self, demos: Batch | None = None) -> None:
        self._centres, self._t = self.demo_context(demos), 0

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: Any = None) -> float:
        self._require_reset(self._centres)
        embedding = self.encoder(check_frame(frame, self.name))[0]
        score = float(self.distance(embedding, torch.tensor(self._t), self._centres))
        self._t += 1
        return score

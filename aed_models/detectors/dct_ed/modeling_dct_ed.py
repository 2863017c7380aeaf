"""DCTED: a DCT-style transformer error detector (after Dance et al. 2021).

An encoder attends across all demonstration frames; a causal decoder over the rollout attends
to them; a linear head gives each frame's error probability. Both use the shared blocks of
`aed_models.nn.attention` (as the DCT policy does), so online a step reuses cached keys and
values and equals the batched pass.
"""

from __future__ import annotations

import re
from typing import Any

import torch
from torch import nn

from aed_models.detectors.base import (
    Batch,
    ErrorDetector,
    PreparedDemos,
    check_demos,
    check_frame,
    rollout_frames,
    rollout_mask,
)
from aed_models.detectors.dct_ed.configuration_dct_ed import DCTEDConfig
from aed_models.losses import masked_bce
from aed_models.nn.attention import DecoderLayer, EncoderLayer, KVCache, sinusoid

KV = tuple[torch.Tensor, torch.Tensor]
# Checkpoints written before DCTED used the shared blocks named the projections in full.
_OLD_PROJECTION = re.compile(r"\.(attn|self_attn|cross_attn)\.(query|key|value)\.")
_SHORT = {"query": "q", "key": "k", "value": "v"}


def rename_old_keys(state_dict: dict[str, Any]) -> dict[str, Any]:
    """Old DCTED keys (`...attn.query.weight`) renamed as the shared blocks name them (`q`)."""
    return {
        _OLD_PROJECTION.sub(lambda m: f".{m[1]}.{_SHORT[m[2]]}.", key): value
        for key, value in state_dict.items()
    }


class DCTED(ErrorDetector):
    requires_policy = False
    output = "probability"
    trains_on = "both"

    def __init__(self, config: DCTEDConfig | None = None):
        from aed_models.nn import build_visual_head

        config = config or DCTEDConfig()
        super().__init__(config)
        self.encoder = build_visual_head(config.visual_head_config())
        sizes = (
            config.feature_dim,
            config.num_heads,
            config.ff_dim,
            config.attn_dropout,
            config.norm_eps,
        )
        self.demo_layers = nn.ModuleList(EncoderLayer(*sizes) for _ in range(config.encoder_layers))
        self.rollout_layers = nn.ModuleList(
            DecoderLayer(*sizes) for _ in range(config.decoder_layers)
        )
        self.classifier = nn.Linear(config.feature_dim, 1)
        self._memory: list[KV] | None = None
        self._memory_mask: torch.Tensor | None = None
        self._cache: list[KVCache] = []
        self._t = 0

    def upgrade_state_dict(self, state_dict: dict[str, Any]) -> dict[str, Any]:
        return rename_old_keys(state_dict)

    # -- demonstrations -----------------------------------------------------------------------
    def encode_demos(self, demos: Batch) -> tuple[torch.Tensor, torch.Tensor]:
        """(1, N L, D) encoded demonstration tokens and their (1, 1, 1, N L) attention mask."""
        from aed_models.nn import encode_frames

        frames, mask = check_demos(demos, self.name)
        n, length = mask.shape
        tokens = encode_frames(self.encoder, frames, mask) + sinusoid(
            torch.arange(length, device=frames.device), self.config.feature_dim
        )
        tokens, mask = tokens.reshape(1, n * length, -1), mask.reshape(1, 1, 1, n * length)
        for layer in self.demo_layers:
            tokens = layer(tokens, mask)
        return tokens, mask

    def memory(self, demos: Batch) -> tuple[list[KV], torch.Tensor]:
        """Each decoder layer's cross-attention keys/values over the demonstrations, and the
        mask."""
        tokens, mask = self.encode_demos(demos)
        return [layer.cross_attn.project_kv(tokens) for layer in self.rollout_layers], mask

    def read_demos(self, demos: Batch | None) -> tuple[list[KV], torch.Tensor]:
        return self.memory(demos)

    # -- rollouts -----------------------------------------------------------------------------
    def _logits(self, rollouts: Batch, demos: Batch | PreparedDemos) -> torch.Tensor:
        from aed_models.nn import encode_frames

        frames, mask = rollout_frames(rollouts)
        memory, memory_mask = self.demo_context(demos)
        x = encode_frames(self.encoder, frames, mask)
        x = x + sinusoid(torch.arange(x.shape[1], device=x.device), self.config.feature_dim)
        b = x.shape[0]
        for layer, (k, v) in zip(self.rollout_layers, memory, strict=True):
            # one environment's demonstrations for every rollout
            x = layer(x, (k.expand(b, -1, -1, -1), v.expand(b, -1, -1, -1)), memory_mask)
        return self.classifier(x).squeeze(-1)

    def loss(
        self, batch: Batch, policy_features: Any = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        rollouts = batch["rollouts"]
        loss = masked_bce(
            self._logits(rollouts, batch["demos"]), rollouts["labels"], rollout_mask(rollouts)
        )
        return loss, {"cls": float(loss.detach())}

    @torch.no_grad()
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        return torch.sigmoid(self._logits(rollouts, demos)) * rollout_mask(rollouts)

    @torch.no_grad()
    def reset(self, demos: Batch | None = None) -> None:
        self._memory, self._memory_mask = self.demo_context(demos)
        self._cache = [KVCache() for _ in self.rollout_layers]
        self._t = 0

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: Any = None) -> float:
        self._require_reset(self._memory)
        x = self.encoder(check_frame(frame, self.name))[:, None]
        x = x + sinusoid(torch.tensor([self._t], device=x.device), self.config.feature_dim)
        for layer, kv, cache in zip(self.rollout_layers, self._memory, self._cache, strict=True):
            x = layer(x, kv, self._memory_mask, cache)
        self._t += 1
        return float(torch.sigmoid(self.classifier(x))[0, 0, 0])

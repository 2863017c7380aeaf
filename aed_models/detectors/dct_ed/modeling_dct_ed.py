"""DCTED: a DCT-style transformer error detector (after Dance et al. 2021).

Demonstration frames (all demonstrations, with sinusoidal time encodings) go through a
transformer encoder (cross-demonstration attention); the rollout's frames go through a causal
decoder whose self-attention sees the rollout so far and whose cross-attention reads the
encoded demonstrations (rollout-demonstration attention); a linear head gives each frame's
error probability.

Online, the decoder runs one frame at a time with each layer's self-attention keys and values
cached, and the demonstrations' cross-attention keys and values computed once at `reset`:
a step does one frame's worth of projections plus one attention row over the cached keys,
exactly what the batched causal pass computes for that frame. Layers are post-norm, as
PyTorch's `nn.Transformer`.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from aed_models.detectors.base import Batch, ErrorDetector, check_frame, demo_mask, rollout_mask
from aed_models.detectors.dct_ed.configuration_dct_ed import DCTEDConfig
from aed_models.losses import masked_bce

KV = tuple[torch.Tensor, torch.Tensor]


def sinusoid(positions: torch.Tensor, dim: int) -> torch.Tensor:
    """(...,) integer positions -> (..., dim) sinusoidal encodings (Vaswani et al.)."""
    half = dim // 2
    freqs = torch.exp(
        -math.log(10000.0)
        * torch.arange(half, dtype=torch.float32, device=positions.device)
        / max(half, 1)
    )
    angles = positions.to(torch.float32)[..., None] * freqs
    out = torch.cat([angles.sin(), angles.cos()], dim=-1)
    return F.pad(out, (0, dim - 2 * half))


class Attention(nn.Module):
    """Multi-head attention whose key/value projections can be computed once and reused."""

    def __init__(self, dim: int, heads: int, dropout: float):
        super().__init__()
        self.heads, self.dropout = heads, dropout
        self.query, self.key, self.value, self.out = (nn.Linear(dim, dim) for _ in range(4))

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        b, n, d = x.shape
        return x.view(b, n, self.heads, d // self.heads).transpose(1, 2)

    def keys_values(self, source: torch.Tensor) -> KV:
        return self._split(self.key(source)), self._split(self.value(source))

    def forward(
        self, x: torch.Tensor, kv: KV, mask: torch.Tensor | None = None, causal: bool = False
    ) -> torch.Tensor:
        q = self._split(self.query(x))
        p = self.dropout if self.training else 0.0
        out = F.scaled_dot_product_attention(
            q, kv[0], kv[1], attn_mask=mask, dropout_p=p, is_causal=causal
        )
        b, h, n, dh = out.shape
        return self.out(out.transpose(1, 2).reshape(b, n, h * dh))


class FeedForward(nn.Sequential):
    def __init__(self, dim: int, hidden: int, dropout: float):
        super().__init__(
            nn.Linear(dim, hidden), nn.ReLU(), nn.Dropout(dropout), nn.Linear(hidden, dim)
        )


class EncoderLayer(nn.Module):
    def __init__(self, c: DCTEDConfig):
        super().__init__()
        d = c.feature_dim
        self.attn = Attention(d, c.num_heads, c.attn_dropout)
        self.ff = FeedForward(d, c.ff_dim, c.attn_dropout)
        self.norm1, self.norm2 = nn.LayerNorm(d, eps=c.norm_eps), nn.LayerNorm(d, eps=c.norm_eps)
        self.drop = nn.Dropout(c.attn_dropout)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x = self.norm1(x + self.drop(self.attn(x, self.attn.keys_values(x), mask)))
        return self.norm2(x + self.drop(self.ff(x)))


class DecoderLayer(nn.Module):
    def __init__(self, c: DCTEDConfig):
        super().__init__()
        d = c.feature_dim
        self.self_attn = Attention(d, c.num_heads, c.attn_dropout)
        self.cross_attn = Attention(d, c.num_heads, c.attn_dropout)
        self.ff = FeedForward(d, c.ff_dim, c.attn_dropout)
        self.norm1, self.norm2, self.norm3 = (nn.LayerNorm(d, eps=c.norm_eps) for _ in range(3))
        self.drop = nn.Dropout(c.attn_dropout)

    def forward(
        self, x: torch.Tensor, self_kv: KV, memory_kv: KV, memory_mask: torch.Tensor, causal: bool
    ) -> torch.Tensor:
        x = self.norm1(x + self.drop(self.self_attn(x, self_kv, causal=causal)))
        x = self.norm2(x + self.drop(self.cross_attn(x, memory_kv, memory_mask)))
        return self.norm3(x + self.drop(self.ff(x)))


class DCTED(ErrorDetector):
    requires_policy = False
    output = "probability"
    trains_on = "both"

    def __init__(self, config: DCTEDConfig | None = None):
        from aed_models.nn import build_visual_head

        config = config or DCTEDConfig()
        super().__init__(config)
        self.encoder = build_visual_head(config.visual_head_config())
        self.demo_layers = nn.ModuleList(EncoderLayer(config) for _ in range(config.encoder_layers))
        self.rollout_layers = nn.ModuleList(
            DecoderLayer(config) for _ in range(config.decoder_layers)
        )
        self.classifier = nn.Linear(config.feature_dim, 1)
        self._memory: list[KV] | None = None
        self._memory_mask: torch.Tensor | None = None
        self._cache: list[KV] = []
        self._t = 0

    # -- demonstrations -----------------------------------------------------------------------
    def encode_demos(self, demos: Batch) -> tuple[torch.Tensor, torch.Tensor]:
        """(1, N L, D) encoded demonstration tokens and their (1, 1, 1, N L) attention mask."""
        from aed_models.nn import encode_frames

        frames, mask = demo_mask(demos, self.name)
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
        return [layer.cross_attn.keys_values(tokens) for layer in self.rollout_layers], mask

    # -- rollouts -----------------------------------------------------------------------------
    def _logits(self, rollouts: Batch, demos: Batch) -> torch.Tensor:
        from aed_models.nn import encode_frames

        mask = rollout_mask(rollouts)
        memory, memory_mask = self.memory(demos)
        x = encode_frames(self.encoder, rollouts["frames"], mask)
        x = x + sinusoid(torch.arange(x.shape[1], device=x.device), self.config.feature_dim)
        b = x.shape[0]
        for layer, (k, v) in zip(self.rollout_layers, memory, strict=True):
            kv = (
                k.expand(b, -1, -1, -1),
                v.expand(b, -1, -1, -1),
            )  # one environment's demos for all
            x = layer(x, layer.self_attn.keys_values(x), kv, memory_mask, causal=True)
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
        self._memory, self._memory_mask = self.memory(demos)
        self._cache = []
        self._t = 0

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: Any = None) -> float:
        self._require_reset(self._memory)
        x = self.encoder(check_frame(frame, self.name))[:, None]
        x = x + sinusoid(torch.tensor([self._t], device=x.device), self.config.feature_dim)
        for i, (layer, kv) in enumerate(zip(self.rollout_layers, self._memory, strict=True)):
            k, v = layer.self_attn.keys_values(x)
            if i < len(self._cache):
                k, v = (
                    torch.cat([self._cache[i][0], k], dim=2),
                    torch.cat([self._cache[i][1], v], dim=2),
                )
                self._cache[i] = (k, v)
            else:
                self._cache.append((k, v))
            x = layer(
                x, (k, v), kv, self._memory_mask, causal=False
            )  # the newest frame sees all cached ones
        self._t += 1
        return float(torch.sigmoid(self.classifier(x))[0, 0, 0])

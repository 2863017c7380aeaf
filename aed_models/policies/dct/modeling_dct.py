"""DCT: a transformer whose encoder fuses all demonstration frames (cross-demonstration
attention) and whose decoder lets each rollout frame attend to them (rollout-demonstration
attention), causally over the rollout. The decoder output at t is the task embedding
f_zeta[t]; the history feature f_h[t] is the visual feature of frame t.

Demonstration frames carry a sinusoidal code of their progress (index / (length - 1)), which
aligns demonstrations of different lengths; the rollout carries only its causal order (its
length is unknown online). Online, each decoder layer caches its self-attention keys and
values and the memory's cross-attention keys and values are computed once per `reset`, so a
step at t = 200 costs about what it costs at t = 10, with the same result as the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from aed_models.nn.attention import DecoderLayer, EncoderLayer, KVCache, progress_encoding
from aed_models.policies.base import DCPolicy
from aed_models.policies.dct.configuration_dct import DCTConfig


@dataclass
class DemoMemory:
    kv: list[
        tuple[torch.Tensor, torch.Tensor]
    ]  # per decoder layer: (1, heads, N * L, head_dim) each
    allowed: torch.Tensor  # (1, 1, 1, N * L) bool: real frames


class DCTPolicy(DCPolicy):
    def __init__(self, config: DCTConfig):
        d = config.visual.out_dim
        super().__init__(config, history_dim=d, task_dim=d)
        args = (d, config.num_heads, config.ff_dim, config.dropout, config.norm_eps)
        self.encoder = nn.ModuleList(EncoderLayer(*args) for _ in range(config.encoder_layers))
        self.decoder = nn.ModuleList(DecoderLayer(*args) for _ in range(config.decoder_layers))

    def encode_demos(
        self, frames: torch.Tensor, mask: torch.Tensor, proprio: torch.Tensor | None
    ) -> DemoMemory:
        n, length = mask.shape
        f = self.embed(frames, mask, proprio)
        steps = torch.arange(length, device=f.device, dtype=f.dtype)
        progress = steps[None] / (mask.sum(1, keepdim=True) - 1).clamp_min(1).to(f.dtype)
        x = (f + progress_encoding(progress, f.shape[-1])).reshape(1, n * length, -1)
        allowed = mask.reshape(1, 1, 1, n * length)
        for layer in self.encoder:
            x = layer(x, allowed)
        return DemoMemory([layer.cross_attn.project_kv(x) for layer in self.decoder], allowed)

    def sequence(
        self, f: torch.Tensor, mask: torch.Tensor, memory: DemoMemory
    ) -> tuple[torch.Tensor, torch.Tensor]:
        b = f.shape[0]
        x = f
        for layer, (k, v) in zip(self.decoder, memory.kv, strict=True):
            x = layer(x, (k.expand(b, -1, -1, -1), v.expand(b, -1, -1, -1)), memory.allowed)
        return f, x

    def init_state(self, memory: DemoMemory) -> list[KVCache]:
        return [KVCache() for _ in self.decoder]

    def step(self, f_t: torch.Tensor, memory: DemoMemory, state: list[KVCache]):
        x = f_t[:, None]
        for layer, kv, cache in zip(self.decoder, memory.kv, state, strict=True):
            x = layer(x, kv, memory.allowed, cache)
        return f_t, x[:, 0], state

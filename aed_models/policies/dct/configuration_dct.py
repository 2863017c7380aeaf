"""DCT (Dance et al. 2021): a transformer from demonstrations to a per-step task embedding."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.policies.configuration_base import PolicyConfig


@dataclass
class DCTConfig(PolicyConfig):
    """Paper's appendix table "Task-embedding network settings" (DCT).

    Args:
        encoder_layers: cross-demonstration attention layers over all demonstration frames.
        decoder_layers: rollout-demonstration attention layers (causal over the rollout).
        num_heads: attention heads; must divide the visual head's `out_dim`.
        ff_dim: hidden size of each layer's feed-forward block (not in the paper; PyTorch's default).
        dropout: dropout in attention and feed-forward.
        norm_eps: LayerNorm epsilon.
    """

    name: ClassVar[str] = "dct"

    encoder_layers: int = 2
    decoder_layers: int = 2
    num_heads: int = 8
    ff_dim: int = 2048
    dropout: float = 0.1
    norm_eps: float = 1e-5

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("encoder_layers", "decoder_layers", "num_heads", "ff_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        if self.visual.out_dim % self.num_heads:
            raise ValueError(f"num_heads={self.num_heads}: must divide visual.out_dim={self.visual.out_dim}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout={self.dropout}: must lie in [0, 1)")
        if self.norm_eps <= 0:
            raise ValueError(f"norm_eps={self.norm_eps}: must be > 0")

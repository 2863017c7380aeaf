"""DCT (Dance et al. 2021): a transformer from demonstrations to a per-step task embedding."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from aed_models.policies.configuration_base import PolicyConfig


@dataclass
class DCTConfig(PolicyConfig):
    """Paper's appendix table "Task-embedding network settings" (DCT).

    Args:
        encoder_layers: cross-demonstration attention layers over all demonstration frames.
        decoder_layers: rollout-demonstration attention layers (causal over the rollout).
        num_heads: attention heads; must divide the visual head's `out_dim`.
        ff_dim: hidden size of each layer's feed-forward block (not in the paper; PyTorch's
            default).
        dropout: dropout in attention and feed-forward.
        norm_eps: LayerNorm epsilon.
    """

    encoder_layers: int = 2
    decoder_layers: int = 2
    num_heads: int = 8
    ff_dim: int = 2048
    dropout: float = 0.1
    norm_eps: float = 1e-5

    @classmethod
    def preset(cls, profile: str) -> DCTConfig:
        """Under mini and demo, 24 frames per demonstration and a smaller feed-forward."""
        config = super().preset(profile)
        return (
            config
            if profile == "paper"
            else dataclasses.replace(config, ff_dim=512, demo_frames=24)
        )

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("encoder_layers", "decoder_layers", "num_heads", "ff_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        if self.visual.out_dim % self.num_heads:
            raise ValueError(
                f"num_heads={self.num_heads}: must divide visual.out_dim={self.visual.out_dim}"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout={self.dropout}: must lie in [0, 1)")
        if self.norm_eps <= 0:
            raise ValueError(f"norm_eps={self.norm_eps}: must be > 0")

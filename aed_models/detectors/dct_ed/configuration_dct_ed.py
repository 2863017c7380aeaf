"""Configuration of DCTED, the DCT-style transformer baseline."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import VisualDetectorConfig, positive
from aed_models.recipe import check_profile


@dataclass
class DCTEDConfig(VisualDetectorConfig):
    """DCTED: visual head, transformer encoder over demonstration frames, causal decoder over
    the rollout attending to them (DCT's settings: 2 + 2 layers, 8 heads, eps 1e-5, dropout 0.1).

    Args:
        num_heads: attention heads (feature_dim must be divisible by it).
        encoder_layers, decoder_layers: layer counts.
        ff_dim: feed-forward width (768 under paper, which gives the paper's parameter count).
        attn_dropout: dropout inside the transformer layers.
        norm_eps: LayerNorm epsilon.
    """

    mini_epochs: ClassVar[int] = 8

    num_heads: int = 8
    encoder_layers: int = 2
    decoder_layers: int = 2
    ff_dim: int = 768
    attn_dropout: float = 0.1
    norm_eps: float = 1e-5

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("num_heads", "decoder_layers", "ff_dim", "norm_eps"):
            positive(name, getattr(self, name))
        if self.encoder_layers < 0:
            raise ValueError(f"encoder_layers={self.encoder_layers}: must be >= 0")
        if self.feature_dim % self.num_heads:
            raise ValueError(
                f"feature_dim={self.feature_dim} is not divisible by num_heads={self.num_heads}"
            )
        if not 0.0 <= self.attn_dropout < 1.0:
            raise ValueError(f"attn_dropout={self.attn_dropout}: must lie in [0, 1)")

    @classmethod
    def preset(cls, profile: str) -> DCTEDConfig:
        check_profile(profile)
        if profile == "paper":
            return cls(arch="resnet18")
        return cls(arch="small_cnn", feature_dim=128, num_heads=4, ff_dim=256)

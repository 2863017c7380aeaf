"""Configuration of the visual heads, importable without torch (CLI help stays fast)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

ARCHS = ("resnet18", "small_cnn")


@dataclass
class VisualHeadConfig:
    """Which per-frame encoder, and its output size.

    Args:
        arch: `resnet18` (the paper's) or `small_cnn` (CPU-sized).
        out_dim: size of the feature vector.
        dropout: dropout after the final FC (the paper: 0.5).
        width: channels of the first conv of `small_cnn` (later layers double it once);
            ignored by `resnet18`.
    """

    arch: Literal["resnet18", "small_cnn"] = "small_cnn"
    out_dim: int = 256
    dropout: float = 0.5
    width: int = 32

    def __post_init__(self) -> None:
        if self.arch not in ARCHS:
            raise ValueError(f"arch={self.arch!r}: known {list(ARCHS)}")
        if self.out_dim < 1:
            raise ValueError(f"out_dim={self.out_dim}: must be >= 1")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout={self.dropout}: must lie in [0, 1)")
        if self.width < 1:
            raise ValueError(f"width={self.width}: must be >= 1")

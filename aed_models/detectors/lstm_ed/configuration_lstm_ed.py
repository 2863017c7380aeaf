"""Configuration of LSTMED, the rollout-only temporal baseline."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import VisualDetectorConfig, positive
from aed_models.recipe import check_profile


@dataclass
class LSTMEDConfig(VisualDetectorConfig):
    """LSTMED: visual head -> LSTM -> MLP, no demonstrations.

    Args:
        hidden_dim: LSTM state size (256 under paper, which gives the paper's parameter count).
        num_layers: stacked LSTM layers.
        head_dim: hidden size of the classifier after the LSTM.
    """

    mini_epochs: ClassVar[int] = 30

    hidden_dim: int = 256
    num_layers: int = 1
    head_dim: int = 64

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("hidden_dim", "num_layers", "head_dim"):
            positive(name, getattr(self, name))

    @classmethod
    def preset(cls, profile: str) -> LSTMEDConfig:
        check_profile(profile)
        return cls(arch="resnet18") if profile == "paper" else cls(arch="small_cnn", hidden_dim=128)

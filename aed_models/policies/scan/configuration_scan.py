"""SCAN (Yeh et al. 2022): stage-conscious attention from the rollout to each demonstration."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from aed_models.policies.configuration_base import PolicyConfig


@dataclass
class SCANConfig(PolicyConfig):
    """Paper's appendix table "Task-embedding network settings" (SCAN): one unidirectional LSTM
    layer.

    Args:
        lstm_hidden: size of the LSTM over the rollout's visual features (the history feature).
        attention_dim: size of the query / key space of the rollout-demonstration attention.
    """

    lstm_hidden: int = 256
    attention_dim: int = 256

    @classmethod
    def preset(cls, profile: str) -> SCANConfig:
        """Under mini and demo, 24 frames per demonstration."""
        config = super().preset(profile)
        return config if profile == "paper" else dataclasses.replace(config, demo_frames=24)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("lstm_hidden", "attention_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")

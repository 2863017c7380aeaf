"""Configuration of TaskEmbED, the single-frame baseline with a NaiveDC task embedding."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import VisualDetectorConfig, positive
from aed_models.recipe import check_profile


@dataclass
class TaskEmbEDConfig(VisualDetectorConfig):
    """TaskEmbED: visual head + MLP on [frame feature, task embedding (2 x feature_dim)].

    Args:
        hidden_dims: the classifier MLP's hidden sizes ((256, 64) under paper, which gives the
            paper's parameter count).
    """

    mini_epochs: ClassVar[int] = 150
    mini_max_frames: ClassVar[int] = 8

    hidden_dims: tuple[int, ...] = (256, 64)

    def __post_init__(self) -> None:
        super().__post_init__()
        self.hidden_dims = tuple(self.hidden_dims)
        for i, h in enumerate(self.hidden_dims):
            positive(f"hidden_dims[{i}]", h)

    @classmethod
    def preset(cls, profile: str) -> TaskEmbEDConfig:
        check_profile(profile)
        return (
            cls(arch="resnet18")
            if profile == "paper"
            else cls(arch="small_cnn", hidden_dims=(128, 64))
        )

"""Configuration of the scene encoder (torch-free)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from aed_models.nn.config import VisualHeadConfig
from aed_models.recipe import Recipe, check_profile


@dataclass
class EncoderConfig:
    """A visual head and a linear read-out of the scene state (`aed_models.data.scene_state`).

    Args:
        visual: the per-frame encoder the policies will reuse, frozen.
        state_names: the read-out's columns (set from the data when training starts).
    """

    visual: VisualHeadConfig = field(
        default_factory=lambda: VisualHeadConfig(arch="small_cnn", out_dim=256, dropout=0.0)
    )
    state_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.visual, dict):
            self.visual = VisualHeadConfig(**self.visual)
        self.state_names = tuple(str(n) for n in self.state_names)

    @classmethod
    def preset(cls, profile: str) -> EncoderConfig:
        """The mini policies' visual head (the paper trains its ResNet18 heads end to end)."""
        check_profile(profile)
        return cls()

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["state_names"] = list(self.state_names)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EncoderConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"EncoderConfig: unknown fields {unknown}; known {sorted(known)}")
        return cls(**data)


@dataclass
class EncoderRecipe(Recipe):
    """Regression of the scene state from single frames, by Adam (`lr`, `weight_decay` are
    Adam's: under RMSprop at the policies' 3e-4 the encoder underfit, "Measured here").

    Args:
        batch_episodes: episodes one update draws frames from (`max_frames` random frames of
            each).
        shift: random-shift augmentation in pixels (0: off).
    """

    batch_episodes: int
    shift: int

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.batch_episodes < 1:
            raise ValueError(f"batch_episodes={self.batch_episodes}: must be >= 1")
        if self.shift < 0:
            raise ValueError(f"shift={self.shift}: must be >= 0")

    @classmethod
    def preset(cls, profile: str) -> EncoderRecipe:
        check_profile(profile)
        epochs = 15 if profile == "demo" else 30
        return cls(
            epochs=epochs,
            lr=1e-3,
            weight_decay=0.0,
            max_frames=8,
            batch_episodes=8,
            shift=4,
        )

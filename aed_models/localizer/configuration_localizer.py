"""Configuration of the demonstration-conditioned target localizer (torch-free)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from aed_models.recipe import Recipe, check_profile


@dataclass
class LocalizerConfig:
    """A fully convolutional matching map and how many stage targets it locates.

    Args:
        width: channels of its first convs (later ones double it).
        dim: size of its unit feature vectors, one per 8 x 8 pixel cell.
        num_targets: stage targets located per episode (the task's stages; set from the
            data when training starts).
        depth_window: a located pixel's depth is the nearest surface within this many pixels
            of it: a match a few pixels off an object's silhouette otherwise reads the table
            behind it. 0 reads the pixel's own, as the localizers saved before this field did
            (they load with it); the `mini` and `demo` presets use 4.
        stride: pixels per side of a matching cell, 8 or 4 (4 times the cells: finer points
            at about twice the cost). Localizers saved before this field load with 8; the
            `mini` and `demo` presets use 4.
        height_tolerance: metres. A located point whose depth puts it further than this from
            the height at which the demonstrations ended its stage is placed at that height
            along its pixel's ray instead: a stage that ends in mid-air (a glass held over its
            coaster) or behind what the camera sees (a handle pushed home) has the depth of
            the surface behind it. 0 = off, as the localizers saved before this field; the
            `mini` and `demo` presets use 0.03.
    """

    width: int = 32
    dim: int = 32
    num_targets: int = 1
    depth_window: int = 0
    stride: int = 8
    height_tolerance: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "dim", "num_targets"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        if self.depth_window < 0:
            raise ValueError(f"depth_window={self.depth_window}: must be >= 0")
        if self.stride not in (4, 8):
            raise ValueError(f"stride={self.stride}: 4 or 8")
        if not (math.isfinite(self.height_tolerance) and self.height_tolerance >= 0):
            raise ValueError(f"height_tolerance={self.height_tolerance}: must be >= 0 (0: off)")
        if self.width % 8:
            raise ValueError(f"width={self.width}: must be a multiple of 8 (GroupNorm of 8)")

    @classmethod
    def preset(cls, profile: str) -> LocalizerConfig:
        check_profile(profile)
        return cls(depth_window=4, stride=4, height_tolerance=0.03)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LocalizerConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"LocalizerConfig: unknown fields {unknown}; known {sorted(known)}")
        return cls(**data)


@dataclass
class LocalizerRecipe(Recipe):
    """Matching of stage targets across episodes of one environment, by Adam.

    An epoch is `updates` updates of `batch` (query, target) pairs; `max_frames` frames are
    read per episode (its first, then random ones before its first stage ends).

    Args:
        updates: updates per epoch (the unit of checkpoints and resume).
        batch: query / target pairs per update.
        colour: strength of the recolouring a query and its target share (0: off).
    """

    updates: int
    batch: int
    colour: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.updates < 1 or self.batch < 1:
            raise ValueError(f"updates={self.updates}, batch={self.batch}: both must be >= 1")
        if not (math.isfinite(self.colour) and 0 <= self.colour < 1):
            raise ValueError(f"colour={self.colour}: must lie in [0, 1)")

    @classmethod
    def preset(cls, profile: str) -> LocalizerRecipe:
        """mini: 8 epochs of 250 updates of 32 pairs; demo: 4 epochs of 50."""
        if check_profile(profile) == "paper":
            raise ValueError("profile='paper': the paper's policies have no localizer")
        demo = profile == "demo"
        return cls(
            epochs=4 if demo else 8,
            lr=1e-3,
            weight_decay=0.0,
            max_frames=6,
            updates=50 if demo else 250,
            batch=32,
            colour=0.3,
        )

"""What every error detector's config holds: its sizes per profile and its training recipe
(torch-free, so CLIs load fast)."""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, TypeVar

from aed_models.recipe import (
    COMPOSITIONS,
    DetectorRecipe,
    Precision,
    check_profile,
    optimiser,
    paper_epochs,
)

C = TypeVar("C", bound="DetectorConfig")


@dataclasses.dataclass
class DetectorConfig:
    """Base of the detector configs: `preset(profile)`, `recipe(profile, task)`, `to_dict()`."""

    # Training under mini (see `recipe`); a detector class sets its own.
    mini_epochs: ClassVar[int] = 30
    mini_max_frames: ClassVar[int] = 0
    mini_composition: ClassVar[tuple[int, int, int]] = (5, 10, 10)
    mini_precision: ClassVar[Precision] = "fp32"

    @classmethod
    def preset(cls: type[C], profile: str) -> C:
        """The sizes of a profile (`paper`: the paper's; `mini`, `demo`: CPU-sized)."""
        check_profile(profile)
        return cls()

    @classmethod
    def recipe(cls, profile: str, task: str) -> DetectorRecipe:
        """How a profile trains: `paper` as the paper (the task's epochs, 5 demonstrations + 10
        successes + 10 failures an iteration, every frame, float32); `mini` the class's
        `mini_*`; `demo` 4 epochs drawing what the demo collects (3 + 4 + 3)."""
        opt = optimiser(profile)
        if profile == "paper":
            return DetectorRecipe(
                epochs=paper_epochs(task),
                lr=opt.lr,
                weight_decay=opt.weight_decay,
                max_frames=0,
                composition=COMPOSITIONS["detector"].drawn(),
                precision="fp32",
            )
        demo = profile == "demo"
        return DetectorRecipe(
            epochs=4 if demo else cls.mini_epochs,
            lr=opt.lr,
            weight_decay=opt.weight_decay,
            max_frames=cls.mini_max_frames,
            composition=(3, 4, 3) if demo else cls.mini_composition,
            precision=cls.mini_precision,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict for checkpoints and logs."""
        return dataclasses.asdict(self)

    @classmethod
    def upgrade_dict(cls, values: dict[str, Any]) -> dict[str, Any]:
        """An older checkpoint's config dict in today's fields (the registry reads every config
        through it). `running_max` (SVDDED, TaskEmbED, RND-OE) became the post-processing of every
        memoryless detector (`aed_models.detectors.postprocess`): True is dropped, False refused."""
        values = dict(values)
        if values.pop("running_max", True) is False:
            raise ValueError(
                "running_max=False: per-frame scores are no longer a config option; the protocol "
                "takes the running maximum of every memoryless detector (its `score` gives the "
                "per-frame outputs)"
            )
        return values


@dataclasses.dataclass
class VisualDetectorConfig(DetectorConfig):
    """Fields shared by the policy-independent baselines: their own per-frame visual head.

    Args:
        arch: `resnet18` (paper) or `small_cnn` (mini, CPU-sized).
        feature_dim: size of the visual head's output.
        dropout: dropout after the head's FC (the paper: 0.5).
        width: first-layer width of `small_cnn`.
    """

    # From-scratch encoders on two cores: more, smaller updates (3 + 4 + 4) teach more per CPU
    # second than the paper's 5 + 10 + 10; their convolutions run under bfloat16 autocast.
    mini_composition: ClassVar[tuple[int, int, int]] = (3, 4, 4)
    mini_precision: ClassVar[Precision] = "bf16"

    arch: str = "small_cnn"
    feature_dim: int = 256
    dropout: float = 0.5
    width: int = 32

    def __post_init__(self) -> None:
        self.visual_head_config()  # validates arch, sizes, dropout

    def visual_head_config(self) -> Any:
        from aed_models.nn.config import VisualHeadConfig

        return VisualHeadConfig(
            arch=self.arch, out_dim=self.feature_dim, dropout=self.dropout, width=self.width
        )


def positive(name: str, value: int | float) -> None:
    if value <= 0:
        raise ValueError(f"{name}={value}: must be > 0")


def nonnegative(name: str, value: int | float) -> None:
    if value < 0:
        raise ValueError(f"{name}={value}: must be >= 0")

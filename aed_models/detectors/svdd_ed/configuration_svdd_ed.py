"""Configuration of SVDDED, the deep one-class baseline."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import VisualDetectorConfig, positive
from aed_models.recipe import Precision, check_profile

CENTRES = ("aligned", "all")


@dataclass
class SVDDEDConfig(VisualDetectorConfig):
    """SVDDED: the visual head alone (paper profile: resnet18 + FC 256).

    Args:
        dropout: 0, as Ruff et al.: dropout's noise on the embedding is a floor under the
            scale-free distance about as large as the distance itself.
        centre: `aligned`: frame t's centre is the demonstrations' mean embedding at step t;
            `all`: the mean of every demonstration frame (the paper's wording), as far from a
            normal frame of one stage as from a wrong one.
        window: `aligned`: the nearest centre of steps t - window .. t + window (rollouts run at
            their own pace).
        eps: added to the centres' mean squared norm in the scale-free distance.
        variance_weight: weight of VICReg's variance hinge on the embeddings, without which the
            small CNN collapses to one point (frozen biases do not prevent it); 0: off.
    """

    mini_epochs: ClassVar[int] = 50
    mini_max_frames: ClassVar[int] = 8
    mini_precision: ClassVar[Precision] = "fp32"  # distances to the centres want float32

    dropout: float = 0.0
    centre: str = "aligned"
    window: int = 10
    eps: float = 1e-6
    variance_weight: float = 25.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.centre not in CENTRES:
            raise ValueError(f"centre={self.centre!r}: one of {CENTRES}")
        positive("eps", self.eps)
        if self.window < 0:
            raise ValueError(f"window={self.window}: must be >= 0")
        if self.variance_weight < 0:
            raise ValueError(f"variance_weight={self.variance_weight}: must be >= 0")

    @classmethod
    def preset(cls, profile: str) -> SVDDEDConfig:
        check_profile(profile)
        return cls(arch="resnet18") if profile == "paper" else cls(arch="small_cnn")

"""Configuration of SVDDED, the deep one-class baseline."""

from __future__ import annotations

from dataclasses import dataclass

from aed_models.detectors.base import VisualDetectorConfig, check_profile, positive


@dataclass
class SVDDEDConfig(VisualDetectorConfig):
    """SVDDED: the visual head alone (paper profile: resnet18 + FC 256, ~11.3M parameters).

    Args:
        eps: added to the centre's squared norm in the scale-free distance.
    """

    eps: float = 1e-6

    def __post_init__(self) -> None:
        super().__post_init__()
        positive("eps", self.eps)

    @classmethod
    def for_profile(cls, profile: str) -> SVDDEDConfig:
        check_profile(profile)
        return cls(arch="resnet18") if profile == "paper" else cls(arch="small_cnn")

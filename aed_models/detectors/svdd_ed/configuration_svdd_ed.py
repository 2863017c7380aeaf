"""Configuration of SVDDED, the deep one-class baseline."""

from __future__ import annotations

from dataclasses import dataclass

from aed_models.detectors.base import VisualDetectorConfig, check_profile, positive


@dataclass
class SVDDEDConfig(VisualDetectorConfig):
    """SVDDED: the visual head alone (paper profile: resnet18 + FC 256, ~11.3M parameters).

    Args:
        eps: added to the centre's squared norm in the scale-free distance.
        variance_weight: weight of a variance floor on the embeddings (VICReg's hinge on each
            dimension's standard deviation over the iteration's frames, target 1; 25 as VICReg's
            variance coefficient). Without it the small CNN collapsed within 3 epochs on Press
            Button (loss exactly 0): with its convolutions driven to zero the spatial softmax is
            uniform and every frame gets the same keypoints, a collapse that frozen biases do not
            prevent; at weight 1 the floor stayed at 0.99 (no variance left) while the distance
            fell to 0.07. 0 switches it off.
    """

    eps: float = 1e-6
    variance_weight: float = 25.0

    def __post_init__(self) -> None:
        super().__post_init__()
        positive("eps", self.eps)
        if self.variance_weight < 0:
            raise ValueError(f"variance_weight={self.variance_weight}: must be >= 0")

    @classmethod
    def for_profile(cls, profile: str) -> SVDDEDConfig:
        check_profile(profile)
        return cls(arch="resnet18") if profile == "paper" else cls(arch="small_cnn")

"""Configuration of SVDDED, the deep one-class baseline."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import VisualDetectorConfig, positive
from aed_models.recipe import check_profile

CENTRES = ("aligned", "all")


@dataclass
class SVDDEDConfig(VisualDetectorConfig):
    """SVDDED: the visual head alone (paper profile: resnet18 + FC 256, ~11.3M parameters).

    Args:
        dropout: 0, unlike the other heads (0.5): dropout's noise on the embedding is a floor
            under the distance (for p = 0.5 its expected square is ||z||^2, the size of the
            whole scale-free distance). Ruff et al.'s networks have no dropout.
        centre: `aligned` (default): the centre of frame t is the mean of the demonstrations'
            embeddings at step t (each demonstration held at its last frame once it has ended);
            `all`: one centre, the mean of every demonstration frame (the paper's wording),
            which is as far from a normal frame of one stage as from a wrong one.
        window: `aligned`: frame t is measured against the nearest of the centres of steps
            t - window .. t + window: the agents run slower than the demonstrations, so step t
            of a rollout is not step t of a demo.
        running_max: score the running maximum of the distance over the frames so far, the
            farthest the rollout has been from the demonstrations
            (`aed_models.detectors.base.running_max`: a single-frame detector cannot learn that
            an error persists).
        eps: added to the centres' mean squared norm in the scale-free distance.
        variance_weight: weight of a variance floor on the embeddings (VICReg's hinge on each
            dimension's standard deviation over the iteration's frames, target 1; 25 as VICReg's
            variance coefficient): without it the small CNN collapses (its convolutions driven
            to zero, the spatial softmax uniform, every frame the same keypoints), which frozen
            biases do not prevent. 0 switches it off.
    """

    mini_epochs: ClassVar[int] = 50
    mini_max_frames: ClassVar[int] = 8

    dropout: float = 0.0
    centre: str = "aligned"
    window: int = 10
    running_max: bool = True
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

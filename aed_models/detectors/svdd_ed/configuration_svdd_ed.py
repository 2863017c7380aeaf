"""Configuration of SVDDED, the deep one-class baseline."""

from __future__ import annotations

from dataclasses import dataclass

from aed_models.detectors.base import VisualDetectorConfig, check_profile, positive

CENTRES = ("aligned", "all")


@dataclass
class SVDDEDConfig(VisualDetectorConfig):
    """SVDDED: the visual head alone (paper profile: resnet18 + FC 256, ~11.3M parameters).

    Args:
        dropout: 0, unlike the other heads (0.5): dropout's noise on the embedding is a floor
            under the distance (for p = 0.5 its expected square is ||z||^2, the size of the
            whole scale-free distance), so with 0.5 the one-class loss sat at 1.00 for 50
            epochs and nothing was learned. Ruff et al.'s networks have no dropout.
        centre: `aligned` (default): the centre of frame t is the mean of the demonstrations'
            embeddings at step t (each demonstration held at its last frame once it has ended);
            `all`: one centre, the mean of every demonstration frame (the paper's wording).
            On Press Button the single centre scored chance on held-out environments (frame
            AUROC 0.505; its one-class loss did not move): a centroid of every phase of a
            multi-stage task is as far from a normal frame of one phase as from a wrong one.
        window: `aligned`: frame t is measured against the nearest of the centres of steps
            t - window .. t + window: the agents run about 20% slower than the demonstrations
            on Press Button (87 vs 70 steps), so step t of a rollout is not step t of a demo.
        running_max: score the running maximum of the distance over the frames so far, the
            farthest the rollout has been from the demonstrations
            (`aed_models.detectors.base.running_max`: a single-frame detector cannot learn that
            an error persists).
        eps: added to the centres' mean squared norm in the scale-free distance.
        variance_weight: weight of a variance floor on the embeddings (VICReg's hinge on each
            dimension's standard deviation over the iteration's frames, target 1; 25 as VICReg's
            variance coefficient). Without it the small CNN collapsed within 3 epochs on Press
            Button (loss exactly 0): with its convolutions driven to zero the spatial softmax is
            uniform and every frame gets the same keypoints, a collapse that frozen biases do not
            prevent; at weight 1 the floor stayed at 0.99 (no variance left) while the distance
            fell to 0.07. 0 switches it off.
    """

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
    def for_profile(cls, profile: str) -> SVDDEDConfig:
        check_profile(profile)
        return cls(arch="resnet18") if profile == "paper" else cls(arch="small_cnn")

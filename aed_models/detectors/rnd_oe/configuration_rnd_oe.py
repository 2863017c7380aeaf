"""Configuration of RND-OE, a failure-free detector on policy features (beyond the paper)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import DetectorConfig, nonnegative, positive
from aed_models.recipe import check_profile


@dataclass
class RNDOEConfig(DetectorConfig):
    """Random network distillation on the policy's per-frame history features.

    Args:
        history_dim: size of the policy's f_h (set from the policy).
        hidden_dim, out_dim: hidden width of the target and predictor MLPs; the target's output.
        scale_momentum: momentum of the running mean training (success) error that errors are
            divided by (~1: as familiar as training successes).
        norm_eps: epsilon of the unit norm of f_h and of the whitening.
        input_clip: whitened inputs are clipped to +-input_clip (RND's 5).
        time_bin: steps per calibration bin (0: one bin for every step).
        max_steps: steps the calibration table covers; later steps use its last bin.
        baseline_steps: the error is divided by its mean over the rollout's own first frames
            (how new the environment is, before any error); 0 = no baseline.
    """

    mini_epochs: ClassVar[int] = 30

    history_dim: int = 256
    hidden_dim: int = 256
    out_dim: int = 64
    scale_momentum: float = 0.99
    norm_eps: float = 1e-5
    input_clip: float = 5.0
    time_bin: int = 5
    max_steps: int = 400
    baseline_steps: int = 10

    def __post_init__(self) -> None:
        for name in ("history_dim", "hidden_dim", "out_dim", "norm_eps", "input_clip", "max_steps"):
            positive(name, getattr(self, name))
        if not 0.0 <= self.scale_momentum < 1.0:
            raise ValueError(f"scale_momentum={self.scale_momentum}: must lie in [0, 1)")
        nonnegative("time_bin", self.time_bin)
        nonnegative("baseline_steps", self.baseline_steps)

    @property
    def num_time_bins(self) -> int:
        return -(-self.max_steps // self.time_bin) if self.time_bin else 1

    @classmethod
    def preset(cls, profile: str) -> RNDOEConfig:
        check_profile(profile)
        return cls() if profile == "paper" else cls(hidden_dim=128, out_dim=32)

"""Configuration of PrObe (Pattern Observer), the paper's policy-dependent detector."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.detectors.configuration_base import DetectorConfig, nonnegative, positive
from aed_models.recipe import check_profile


@dataclass
class ProbeConfig(DetectorConfig):
    """PrObe's sizes and objective weights (the paper gives no weights, margin or clipping:
    these defaults are ours).

    Args:
        history_dim, task_dim: sizes of the policy's f_h and f_zeta (set from the policy).
        hidden_dim, embed_dim: pattern-flow LSTM and task-transform size; logit-embedding size.
        use_pattern_extractor: False: the ablation's naive model (FC + instance norm on f_h).
        lambda_cls, lambda_pat, lambda_tem: weights of L_cls, L_pat, L_tem (0 switches one off).
        margin, alpha: the triplet margin m and how temporal distance moves it,
            m_t = m (1 - alpha (d_ap - d_an)).
        clip: temporal distances (fractions of the rollout's length) are clipped here.
        triplets_per_rollout: anchors sampled in each failed rollout per iteration.
        norm_eps: epsilon of the unit-norm and instance norms.
    """

    mini_epochs: ClassVar[int] = 30

    history_dim: int = 256
    task_dim: int = 256
    hidden_dim: int = 256
    embed_dim: int = 64
    use_pattern_extractor: bool = True
    lambda_cls: float = 1.0
    lambda_pat: float = 0.1
    lambda_tem: float = 0.5
    margin: float = 1.0
    alpha: float = 0.5
    clip: float = 0.5
    triplets_per_rollout: int = 16
    norm_eps: float = 1e-5

    def __post_init__(self) -> None:
        for name in (
            "history_dim",
            "task_dim",
            "hidden_dim",
            "embed_dim",
            "triplets_per_rollout",
            "clip",
            "norm_eps",
        ):
            positive(name, getattr(self, name))
        for name in ("lambda_cls", "lambda_pat", "lambda_tem", "margin", "alpha"):
            nonnegative(name, getattr(self, name))
        if self.lambda_cls + self.lambda_pat + self.lambda_tem == 0:
            raise ValueError("lambda_cls, lambda_pat and lambda_tem are all 0: nothing to train")

    @classmethod
    def preset(cls, profile: str) -> ProbeConfig:
        check_profile(profile)
        return cls() if profile == "paper" else cls(hidden_dim=128, embed_dim=32)

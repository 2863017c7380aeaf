"""What every demonstration-conditioned policy's config holds (torch-free, so CLIs load fast)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from aed_models.nn.config import VisualHeadConfig


@dataclass
class PolicyConfig:
    """Shared parts: the visual head and the actor (paper, appendix table "General components").

    Args:
        visual: the per-frame encoder, shared by the rollout and the demonstrations.
        actor_hidden: hidden sizes of the actor MLP (paper: 256, 64); its input is the
            history feature and the task embedding concatenated.
        inverse_dynamics: add a head predicting the action between consecutive frames
            (the paper's optional module; an auxiliary loss only).
        inverse_dynamics_weight: weight of that loss.
        grip_loss: `bce` on open (+1) / closed (-1), or `mse` on the standardised value.
        proprio: also read the TCP position and finger joints (`aed_models.data.PROPRIO_DIM`),
            embedded linearly and added to every frame's visual feature. The paper's policies
            read RGB-D only (off under `paper`); from-scratch CNNs on a CPU budget learn where
            the gripper is too slowly without it (on under `mini`).
        subgoal_weight: weight of a stage-target loss (0 = off, the paper's policies). A linear
            head predicts, from [f_h, f_zeta], the offset from the TCP to where the current stage
            ends (`aed_models.data.stage_subgoals`, read from the stored TCP poses, no simulator
            state), and the actor reads that prediction beside [f_h, f_zeta]. Why: with the true
            offset, an MLP predicts the expert's Press Button actions to 0.10 of their variance,
            without it to 0.26; behaviour cloning alone did not teach the small CNN where the
            button is (on under `mini`). As an auxiliary loss only (the actor not reading it),
            it did not lower the action loss (0.62 vs 0.61 of the variance).
        demo_frames: encode at most this many frames of each demonstration, evenly spread
            (first and last kept), in training and online alike; 0 = every frame. It bounds the
            cost of DCT's and SCAN's demonstration memory (NaiveDC reads only the ends).
    """

    name: ClassVar[str] = ""

    visual: VisualHeadConfig = field(default_factory=VisualHeadConfig)
    actor_hidden: tuple[int, ...] = (256, 64)
    inverse_dynamics: bool = False
    inverse_dynamics_weight: float = 1.0
    grip_loss: Literal["bce", "mse"] = "bce"
    proprio: bool = False
    demo_frames: int = 0
    subgoal_weight: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.visual, dict):
            self.visual = VisualHeadConfig(**self.visual)
        if not isinstance(self.visual, VisualHeadConfig):
            raise ValueError(f"visual={self.visual!r}: must be a VisualHeadConfig")
        self.actor_hidden = tuple(int(h) for h in self.actor_hidden)
        if not self.actor_hidden or min(self.actor_hidden) < 1:
            raise ValueError(f"actor_hidden={self.actor_hidden}: needs at least one size, all >= 1")
        if self.inverse_dynamics_weight < 0:
            raise ValueError(f"inverse_dynamics_weight={self.inverse_dynamics_weight}: must be >= 0")
        if self.subgoal_weight < 0:
            raise ValueError(f"subgoal_weight={self.subgoal_weight}: must be >= 0")
        if self.subgoal_weight > 0 and not self.proprio:
            raise ValueError("subgoal_weight > 0 needs proprio=True (the offset is from the TCP the policy reads)")
        if self.demo_frames < 0 or self.demo_frames == 1:
            raise ValueError(f"demo_frames={self.demo_frames}: 0 (all) or >= 2")
        if self.grip_loss not in ("bce", "mse"):
            raise ValueError(f"grip_loss={self.grip_loss!r}: bce or mse")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (lists, not tuples) for checkpoints and logs."""
        return _plain(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PolicyConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"{cls.__name__}: unknown fields {unknown}; known {sorted(known)}")
        return cls(**data)


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value

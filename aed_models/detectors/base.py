"""The interface every error detector implements, and the pieces the visual baselines share.

A detector says, per frame of an agent rollout, how likely a behaviour error is (`output =
"probability"`) or how far the frame lies from normal behaviour (`"distance"`), two ways that
agree to 1e-5 in eval mode: batched, `score(rollouts, demos, policy_features) -> (B, T)`, and
online, `reset(demos)` then `step(frame, policy_features) -> float` with constant state per
step. Scoring many rollouts of one environment, `prepare(demos)` reads the demonstrations once
(a detector's embeddings or memory of them) and stands for them in `score`, `embed` and
`reset`. Both give per-frame outputs; scoring and monitoring post-process them in one place
(`aed_models.detectors.postprocess`). Policy-dependent detectors (`requires_policy`) read the
frozen policy's history features f_h (B, T, Dh) and task embedding f_zeta (B, T, Dz) instead
of frames; online, the pair the policy's `features()` returns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import torch
from torch import nn

from aed_models.nn.batch import check_sequences

Batch = dict[str, Any]


def to_device(value: Any, device: torch.device) -> Any:
    """Tensors inside nested dicts / tuples / lists moved to `device`; anything else as is."""
    if isinstance(value, torch.Tensor):
        return value.to(device, non_blocking=True)
    if isinstance(value, dict):
        return {k: to_device(v, device) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return type(value)(to_device(v, device) for v in value)
    return value


def split_features(
    policy_features: Any, what: str = "policy_features"
) -> tuple[torch.Tensor, torch.Tensor]:
    """(history, task) from a `PolicyFeatures`, a (history, task) pair, or a dict with those
    keys."""
    if policy_features is None:
        raise ValueError(
            f"{what} is None: this detector reads the policy's features (history, task)"
        )
    if hasattr(policy_features, "history") and hasattr(policy_features, "task"):
        return policy_features.history, policy_features.task
    if isinstance(policy_features, dict) and {"history", "task"} <= policy_features.keys():
        return policy_features["history"], policy_features["task"]
    if isinstance(policy_features, (tuple, list)) and len(policy_features) == 2:
        return policy_features[0], policy_features[1]
    raise TypeError(
        f"{what} of type {type(policy_features).__name__}: expected PolicyFeatures, "
        "(history, task) or a dict"
    )


@dataclass(frozen=True, eq=False)
class PreparedDemos:
    """One environment's demonstrations as one detector reads them (`ErrorDetector.prepare`)."""

    detector: ErrorDetector
    value: Any


class ErrorDetector(nn.Module):
    """Base class: see the module docstring. Subclasses set the class attributes and implement
    `loss`, `score`, `reset` and `step`."""

    name: ClassVar[str] = ""  # the registry key, set by the registry
    requires_policy: ClassVar[bool] = False
    output: ClassVar[Literal["probability", "distance"]] = "probability"
    trains_on: ClassVar[Literal["both", "successes"]] = "both"
    # Scores each frame alone: the protocol reads the running maximum of its outputs
    # (`aed_models.detectors.postprocess`).
    memoryless: ClassVar[bool] = False

    def __init__(self, config: Any):
        super().__init__()
        self.config = config

    # -- training ---------------------------------------------------------------------------
    def loss(
        self, batch: Batch, policy_features: Any = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Training loss on one iteration's batch (`aed_models.data.EnvironmentIterations`).

        `policy_features` (policy-dependent detectors): the rollouts' (history, task) features,
        aligned with `batch["rollouts"]["mask"]`. Returns the loss and its named parts.
        """
        raise NotImplementedError

    # -- demonstrations -----------------------------------------------------------------------
    def read_demos(self, demos: Batch | None) -> Any:
        """What the detector reads of an environment's demonstrations (`frames`, `mask`): the
        demonstrations themselves, unless a subclass encodes them."""
        return demos

    @torch.no_grad()
    def prepare(self, demos: Batch | None) -> PreparedDemos:
        """`read_demos(demos)` once, to pass as the demonstrations of every rollout of their
        environment."""
        return PreparedDemos(self, self.read_demos(demos))

    def demo_context(self, demos: Batch | PreparedDemos | None) -> Any:
        """`read_demos(demos)`, or what `prepare` computed of them."""
        if not isinstance(demos, PreparedDemos):
            return self.read_demos(demos)
        if demos.detector is not self:
            raise ValueError(
                f"{self.name}: demonstrations prepared by another detector "
                f"({demos.detector.name}); call this detector's prepare(demos)"
            )
        return demos.value

    # -- inference --------------------------------------------------------------------------
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        """(B, T) per-frame scores of padded rollouts (`frames`, `mask`); 0 on padding."""
        raise NotImplementedError

    def reset(self, demos: Batch | None = None) -> None:
        """Start a new rollout given this environment's demonstrations (`frames`, `mask`)."""
        raise NotImplementedError

    def step(
        self,
        frame: torch.Tensor | None = None,
        policy_features: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> float:
        """Score of the newest frame (4, H, W), or of the policy's newest (f_h, f_zeta)."""
        raise NotImplementedError

    @torch.no_grad()
    def embed(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        """(B, T, E) per-frame embeddings of padded rollouts: what the detector's last layer
        reads (the input of the last `nn.Linear` of its `classifier`), for visualisation."""
        classifier = getattr(self, "classifier", None)
        linears = [
            m for m in (classifier.modules() if classifier else ()) if isinstance(m, nn.Linear)
        ]
        if not linears:
            raise NotImplementedError(f"{self.name}: no classifier layer whose input to embed")
        seen: list[torch.Tensor] = []
        hook = linears[-1].register_forward_pre_hook(lambda _, args: seen.append(args[0]))
        try:
            self.score(rollouts, demos, policy_features)
        finally:
            hook.remove()
        if len(seen) != 1 or seen[0].dim() != 3:
            raise RuntimeError(f"{self.name}: its classifier did not read one (B, T, E) batch")
        return seen[0]

    # -- bookkeeping ------------------------------------------------------------------------
    def upgrade_state_dict(self, state_dict: dict[str, Any]) -> dict[str, Any]:
        """A state dict of an older layout in today's keys (identity unless a detector renamed
        its modules); every load goes through it, so older checkpoints keep loading."""
        return state_dict

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        return super().load_state_dict(self.upgrade_state_dict(state_dict), strict, assign)

    def num_parameters(self, trainable_only: bool = False) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad or not trainable_only)

    def _require_reset(self, state: Any) -> None:
        if state is None:
            raise RuntimeError(f"{self.name}: call reset(demos) before step()")


def rollout_mask(rollouts: Batch) -> torch.Tensor:
    """The (B, T) boolean mask of a rollouts dict, checked."""
    if "mask" not in rollouts:
        raise KeyError("rollouts has no 'mask' (B, T): pad with aed_models.data.pad_sequences")
    return rollouts["mask"].bool()


def steps_of(sequences: Batch, mask: torch.Tensor) -> torch.Tensor:
    """(B, L) step of each frame in its episode: `source` where the batch keeps it (frames
    subsampled or augmented in training), else the frame's position."""
    source = sequences.get("source")
    return (
        source
        if source is not None
        else torch.arange(mask.shape[1], device=mask.device).expand_as(mask)
    )


def rollout_frames(rollouts: Batch) -> tuple[torch.Tensor, torch.Tensor]:
    """(frames (B, T, 4, H, W), mask (B, T)) of a rollouts dict, checked."""
    rollout_mask(rollouts)
    return check_sequences(rollouts, "rollouts", features=False)


def check_demos(demos: Batch | None, name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """(frames (N, L, 4, H, W), mask (N, L)) of a demos dict, checked."""
    if demos is None:
        raise ValueError(
            f"{name} needs demonstrations: a dict with frames (N, L, 4, H, W) and mask (N, L)"
        )
    return check_sequences(demos, f"{name} demos", features=False)


def check_frame(frame: torch.Tensor | None, name: str) -> torch.Tensor:
    """A single frame (4, H, W) as a batch of one (1, 4, H, W)."""
    if frame is None:
        raise ValueError(f"{name} reads frames: step(frame=(4, H, W)) got None")
    if frame.dim() != 3:
        raise ValueError(f"frame of shape {tuple(frame.shape)}: expected (4, H, W)")
    return frame[None]

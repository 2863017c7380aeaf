"""What every demonstration-conditioned policy's config holds (torch-free, so CLIs load fast)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, TypeVar

from aed_models.localizer.configuration_localizer import LocalizerConfig
from aed_models.nn.config import VisualHeadConfig
from aed_models.recipe import COMPOSITIONS, PolicyRecipe, check_profile, optimiser, paper_epochs

C = TypeVar("C", bound="PolicyConfig")


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
            ends (`aed_models.data.stage_subgoals`, from the stored TCP poses), and the actor
            reads that prediction: behaviour cloning alone did not teach the small CNN where
            the target is (on under `mini`; the README's "Measured here" says how much it helps).
        subgoal_head: `linear`, that head; or `pointer` (needs a localizer): a softmax choice
            among the offsets to the located points plus a linear residual, whose prediction
            also enters the position action through a learned per-axis gain (under `mini`,
            where the actor otherwise ignored the located coordinates).
        frozen_encoder: the visual head is the task's scene encoder (`aed train-encoder`, trained
            to say where things are), frozen; training reads its cached per-frame features. The
            paper trains its heads end to end (off under `paper`, on under `mini`).
        localizer: a frozen demonstration-conditioned target localizer (`aed train-localizer`):
            at a rollout's first frame it places each stage's target where the demonstrations
            show it, and the actor (and the stage-target head) read the offsets from the TCP to
            those points. None under `paper` (the paper's policies act from RGB-D alone); on
            under `mini`, where the scene encoder alone did not find novel objects.
        demo_frames: encode at most this many frames of each demonstration, evenly spread
            (first and last kept), in training and online alike; 0 = every frame. It bounds the
            cost of DCT's and SCAN's demonstration memory (NaiveDC reads only the ends).
        action_chunk: the actor predicts this step's action and the next `action_chunk - 1`
            (ACT's action chunking); online, every step's action is the exponentially
            weighted mean of what the last `action_chunk` steps predicted for it (ACT's
            temporal ensembling). 1 = one action per step (the paper's); under `mini` the
            class's `mini_action_chunk` (DCT and SCAN 10, NaiveDC 1).
    """

    # Training draws under mini and demo (see `recipe`); a policy class may change them.
    mini_composition: ClassVar[tuple[int, int]] = (5, 2)
    demo_composition: ClassVar[tuple[int, int]] = (3, 2)
    mini_max_frames: ClassVar[int] = 0
    mini_rollout_frames: ClassVar[str] = "even"
    mini_action_chunk: ClassVar[int] = 10  # under mini and demo
    mini_feature_dropout: ClassVar[float] = 0.5  # under mini and demo

    visual: VisualHeadConfig = field(default_factory=VisualHeadConfig)
    actor_hidden: tuple[int, ...] = (256, 64)
    inverse_dynamics: bool = False
    inverse_dynamics_weight: float = 1.0
    grip_loss: Literal["bce", "mse"] = "bce"
    proprio: bool = False
    demo_frames: int = 0
    subgoal_weight: float = 0.0
    subgoal_head: Literal["linear", "pointer"] = "linear"
    frozen_encoder: bool = False
    localizer: LocalizerConfig | None = None
    action_chunk: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.visual, dict):
            self.visual = VisualHeadConfig(**self.visual)
        if isinstance(self.localizer, dict):
            self.localizer = LocalizerConfig.from_dict(self.localizer)
        if not isinstance(self.visual, VisualHeadConfig):
            raise ValueError(f"visual={self.visual!r}: must be a VisualHeadConfig")
        self.actor_hidden = tuple(int(h) for h in self.actor_hidden)
        if not self.actor_hidden or min(self.actor_hidden) < 1:
            raise ValueError(f"actor_hidden={self.actor_hidden}: needs at least one size, all >= 1")
        if self.inverse_dynamics_weight < 0:
            raise ValueError(
                f"inverse_dynamics_weight={self.inverse_dynamics_weight}: must be >= 0"
            )
        if self.subgoal_weight < 0:
            raise ValueError(f"subgoal_weight={self.subgoal_weight}: must be >= 0")
        if self.subgoal_weight > 0 and not self.proprio:
            raise ValueError(
                "subgoal_weight > 0 needs proprio=True "
                "(the offset is from the TCP the policy reads)"
            )
        if self.subgoal_head not in ("linear", "pointer"):
            raise ValueError(f"subgoal_head={self.subgoal_head!r}: linear or pointer")
        if self.subgoal_head == "pointer" and self.localizer is None:
            raise ValueError(
                "subgoal_head='pointer' needs a localizer (it points at the located targets)"
            )
        if self.localizer is not None and not self.proprio:
            raise ValueError(
                "localizer needs proprio=True (the policy reads the offsets from the TCP)"
            )
        if self.demo_frames < 0 or self.demo_frames == 1:
            raise ValueError(f"demo_frames={self.demo_frames}: 0 (all) or >= 2")
        if self.action_chunk < 1:
            raise ValueError(f"action_chunk={self.action_chunk}: must be >= 1")
        if self.grip_loss not in ("bce", "mse"):
            raise ValueError(f"grip_loss={self.grip_loss!r}: bce or mse")

    @classmethod
    def preset(cls: type[C], profile: str) -> C:
        """The sizes of a profile: `paper` the paper's (ResNet18 head, RGB-D only); `mini` and
        `demo` CPU-sized (the task's frozen scene encoder as the visual head, proprioception, a
        pointer stage-target head, the task's target localizer, the class's action chunks)."""
        if check_profile(profile) == "paper":
            return cls(visual=VisualHeadConfig(arch="resnet18", out_dim=256, dropout=0.5))
        small = VisualHeadConfig(arch="small_cnn", out_dim=256, dropout=0.0, width=32)
        return cls(
            visual=small,
            proprio=True,
            subgoal_weight=1.0,
            subgoal_head="pointer",
            frozen_encoder=True,
            localizer=LocalizerConfig.preset(profile),
            action_chunk=cls.mini_action_chunk,
        )

    @classmethod
    def recipe(cls, profile: str, task: str) -> PolicyRecipe:
        """How a profile trains: `paper` as the paper (its epochs per task, 5 demonstrations +
        10 successes an iteration, every frame); `mini` more, smaller updates with a random
        shift (the class's `mini_*` draws); `demo` the mini recipe for 20 epochs, drawing at
        most what the demo collects."""
        if check_profile(profile) == "paper":
            opt = optimiser(profile)
            return PolicyRecipe(
                epochs=paper_epochs(task),
                lr=opt.lr,
                weight_decay=opt.weight_decay,
                max_frames=0,
                composition=COMPOSITIONS["policy"].drawn()[:2],
                rollout_frames="even",
                shift=0,
                feature_dropout=0.0,
            )
        opt = optimiser(profile)
        return PolicyRecipe(
            epochs=20 if profile == "demo" else 100,
            lr=opt.lr,
            weight_decay=opt.weight_decay,
            max_frames=cls.mini_max_frames,
            composition=cls.demo_composition if profile == "demo" else cls.mini_composition,
            rollout_frames=cls.mini_rollout_frames,
            shift=0,  # the frozen encoder was trained shifted; its features are cached
            feature_dropout=cls.mini_feature_dropout,
        )

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

"""Profiles and training recipes: the shared vocabulary of every model's `preset` and `recipe`.

A profile names one consistent size of everything: `paper` (the paper's models and training, for a
GPU), `mini` (CPU-sized models that learn on two cores) and `demo` (the mini models, briefly
trained, as `aed demo` runs them). Each model's config class owns its sizes
(`preset(profile)`) and its training recipe (`recipe(profile, task)`); this module holds only
what they share: the paper's epoch table and the two optimiser settings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

PROFILES = ("mini", "paper", "demo")
Profile = Literal["mini", "paper", "demo"]
PRECISIONS = ("fp32", "bf16")
Precision = Literal["fp32", "bf16"]

# Paper, appendix table "FSI task configurations": epochs per task (policies and detectors).
PAPER_EPOCHS = {
    "CloseDrawer": 160,
    "PressButton": 40,
    "PickPlace": 50,
    "MoveGlassCup": 50,
    "OrganizeTable": 50,
    "BackToBox": 50,
    "FactoryPacking": 80,
}


@dataclass(frozen=True)
class Composition:
    """How many episodes of each kind one training iteration draws from one environment."""

    num_demos: int
    num_successes: int
    num_failures: int = 0

    def __post_init__(self) -> None:
        for name in ("num_demos", "num_successes", "num_failures"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 0")

    def drawn(self) -> tuple[int, int, int]:
        return self.num_demos, self.num_successes, self.num_failures


# The paper's (appendix "Training details"): policies 5 demonstrations + 10 successes;
# detectors + 10 failures; SVDDED (trained on successes only) 5 + 20.
COMPOSITIONS: dict[str, Composition] = {
    "policy": Composition(5, 10, 0),
    "detector": Composition(5, 10, 10),
    "svdd": Composition(5, 20, 0),
}


@dataclass(frozen=True)
class Optimiser:
    """RMSprop's learning rate and L2 weight decay."""

    lr: float
    weight_decay: float


# The paper's (appendix "Training details"); mini: from-scratch small CNNs learn faster with a
# larger step and no L2 term (the README's "Measured here" says why).
PAPER_OPTIMISER = Optimiser(lr=1e-4, weight_decay=1e-2)
MINI_OPTIMISER = Optimiser(lr=3e-4, weight_decay=0.0)


def check_profile(profile: str) -> str:
    if profile not in PROFILES:
        raise ValueError(f"profile={profile!r}: known {list(PROFILES)}")
    return profile


def optimiser(profile: str) -> Optimiser:
    return PAPER_OPTIMISER if check_profile(profile) == "paper" else MINI_OPTIMISER


def paper_epochs(task: str) -> int:
    if task not in PAPER_EPOCHS:
        raise ValueError(f"task={task!r}: no paper epoch count (known {sorted(PAPER_EPOCHS)})")
    return PAPER_EPOCHS[task]


@dataclass
class Recipe:
    """What every training recipe holds: epochs, the optimiser, frames per episode.

    Args:
        epochs: passes over every training environment.
        lr: RMSprop learning rate.
        weight_decay: L2 weight.
        max_frames: frames per episode per iteration, evenly spread; 0 = every frame.
    """

    epochs: int
    lr: float
    weight_decay: float
    max_frames: int

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"epochs={self.epochs}: must be >= 1")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr={self.lr}: must be a finite number > 0")
        if not (math.isfinite(self.weight_decay) and self.weight_decay >= 0):
            raise ValueError(f"weight_decay={self.weight_decay}: must be a finite number >= 0")
        if self.max_frames < 0 or self.max_frames == 1:
            raise ValueError(f"max_frames={self.max_frames}: 0 (all) or >= 2")


@dataclass
class PolicyRecipe(Recipe):
    """Behaviour cloning of a policy.

    Args:
        composition: demonstrations and agent successes one iteration draws from one environment.
        rollout_frames: how `max_frames` picks rollout frames: even, or a fresh random subset
            per draw.
        shift: random-shift augmentation in pixels, per sequence (0: off).
        feature_dropout: the chance that a training rollout's cached visual features are zeroed
            for the whole sequence, so that the actor also learns to act from the located
            points and proprioception alone; online the features are always on (0: off).
    """

    composition: tuple[int, int]
    rollout_frames: Literal["even", "random"]
    shift: int
    feature_dropout: float

    def __post_init__(self) -> None:
        super().__post_init__()
        self.composition = tuple(int(n) for n in self.composition)
        if len(self.composition) != 2 or min(self.composition) < 1:
            raise ValueError(f"composition={self.composition}: (demos >= 1, successes >= 1)")
        if self.rollout_frames not in ("even", "random"):
            raise ValueError(f"rollout_frames={self.rollout_frames!r}: even or random")
        if self.shift < 0:
            raise ValueError(f"shift={self.shift}: must be >= 0")
        if not 0 <= self.feature_dropout < 1:
            raise ValueError(f"feature_dropout={self.feature_dropout}: must be in [0, 1)")


@dataclass
class DetectorRecipe(Recipe):
    """Training of an error detector.

    Args:
        composition: demonstrations, agent successes and agent failures one iteration draws
            from one environment; a detector trained on successes only draws successes in the
            failures' place.
        precision: `fp32`, or `bf16`: the forward pass and loss under bfloat16 autocast (the
            weights, their gradients and the optimiser stay float32; scoring is float32).
    """

    composition: tuple[int, int, int]
    precision: Precision

    def __post_init__(self) -> None:
        super().__post_init__()
        self.composition = tuple(int(n) for n in self.composition)
        if len(self.composition) != 3 or min(self.composition) < 0 or self.composition[0] < 1:
            raise ValueError(
                f"composition={self.composition}: (demos >= 1, successes >= 0, failures >= 0)"
            )
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision={self.precision!r}: known {list(PRECISIONS)}")

"""NaiveDC (James et al. 2018): the task is the mean over demonstrations of (first, last) frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.policies.configuration_base import PolicyConfig


@dataclass
class NaiveDCConfig(PolicyConfig):
    """No parameters beyond the shared ones: the task embedding has twice the visual size."""

    # Single frames: more successes an iteration, each a fresh random subset of 8 frames (more
    # scenes per update for the same cost).
    mini_composition: ClassVar[tuple[int, int]] = (5, 8)
    demo_composition: ClassVar[tuple[int, int]] = (3, 4)
    mini_max_frames: ClassVar[int] = 8
    mini_rollout_frames: ClassVar[str] = "random"
    # It acts from the current frame alone: on the ensemble of chunks it stopped succeeding
    # (the README's "Measured here").
    mini_action_chunk: ClassVar[int] = 1

"""NaiveDC (James et al. 2018): the task is the mean over demonstrations of (first, last) frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aed_models.policies.configuration_base import PolicyConfig


@dataclass
class NaiveDCConfig(PolicyConfig):
    """No parameters beyond the shared ones: the task embedding has twice the visual size."""

    name: ClassVar[str] = "naive_dc"

"""Demonstration-conditioned policies, looked up by name: `naive_dc`, `dct`, `scan`.

    policy = make_policy("dct")                     # the mini preset
    config = POLICIES.preset("dct", "paper")        # the paper's sizes
    recipe = POLICIES.recipe("dct", "mini", "PressButton")
    policy = load_policy("runs/PressButton/policies/dct/policy.pt")

Configs import without torch; a policy's modelling module is imported only when one is built.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from aed_models.policies.configuration_base import PolicyConfig
from aed_models.policies.dct.configuration_dct import DCTConfig
from aed_models.policies.naive_dc.configuration_naive_dc import NaiveDCConfig
from aed_models.policies.scan.configuration_scan import SCANConfig
from aed_models.registry import ModelRegistry

if TYPE_CHECKING:
    from aed_models.policies.base import DCPolicy

POLICIES = ModelRegistry(
    family="policy",
    package="aed_models.policies",
    classes={
        "naive_dc": ("NaiveDCConfig", "NaiveDCPolicy"),
        "dct": ("DCTConfig", "DCTPolicy"),
        "scan": ("SCANConfig", "SCANPolicy"),
    },
)
FAMILY = POLICIES.family


def make_policy(name: str, config: PolicyConfig | dict | None = None, **overrides: Any) -> DCPolicy:
    """A freshly initialised policy; `config` defaults to the mini preset, `overrides` replace
    fields."""
    return POLICIES.make(name, config, **overrides)


def load_policy(path: Path | str, name: str | None = None, map_location: str = "cpu") -> DCPolicy:
    """A policy from a checkpoint of `train_policy` (or `save_policy`), in eval mode."""
    return POLICIES.load(path, name, map_location)


def save_policy(path: Path | str, policy: DCPolicy, extra: dict | None = None) -> str:
    """Write `policy` (config + weights + action stats) as a checkpoint; returns its sha256."""
    return POLICIES.save(path, policy, extra)


__all__ = [
    "FAMILY",
    "POLICIES",
    "DCTConfig",
    "NaiveDCConfig",
    "PolicyConfig",
    "SCANConfig",
    "load_policy",
    "make_policy",
    "save_policy",
]

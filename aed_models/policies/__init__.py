"""Demonstration-conditioned policies, looked up by name: `naive_dc`, `dct`, `scan`.

Configs import without torch; a policy's modelling module is imported only when a model is
built (so `aed --help` stays fast).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from aed_models.nn.config import VisualHeadConfig
from aed_models.policies.configuration_base import PolicyConfig
from aed_models.policies.dct.configuration_dct import DCTConfig
from aed_models.policies.naive_dc.configuration_naive_dc import NaiveDCConfig
from aed_models.policies.scan.configuration_scan import SCANConfig

if TYPE_CHECKING:
    from aed_models.policies.base import DCPolicy

FAMILY = "policy"  # checkpoint family

# name -> (config class, "module:class" of the model)
POLICIES: dict[str, tuple[type[PolicyConfig], str]] = {
    "naive_dc": (NaiveDCConfig, "aed_models.policies.naive_dc.modeling_naive_dc:NaiveDCPolicy"),
    "dct": (DCTConfig, "aed_models.policies.dct.modeling_dct:DCTPolicy"),
    "scan": (SCANConfig, "aed_models.policies.scan.modeling_scan:SCANPolicy"),
}

PROFILES = ("mini", "paper")


def _check_name(name: str) -> None:
    if name not in POLICIES:
        raise ValueError(f"unknown policy {name!r}; known policies: {', '.join(POLICIES)}")


def policy_config(name: str, profile: Literal["mini", "paper"] = "paper", **overrides: Any) -> PolicyConfig:
    """The config of `name` for a profile: `paper` = the paper's sizes (ResNet18 head);
    `mini` = CPU-sized (small CNN head, no dropout, smaller feed-forward, proprioception, a
    stage-target head read by the actor, 24 frames per demonstration)."""
    _check_name(name)
    if profile not in PROFILES:
        raise ValueError(f"profile={profile!r}: known {list(PROFILES)}")
    config_cls = POLICIES[name][0]
    if profile == "paper":
        defaults: dict[str, Any] = {"visual": VisualHeadConfig(arch="resnet18", out_dim=256, dropout=0.5)}
    else:
        defaults = {"visual": VisualHeadConfig(arch="small_cnn", out_dim=256, dropout=0.0, width=32), "proprio": True,
                    "subgoal_weight": 1.0}
        if name == "dct":
            defaults["ff_dim"] = 512
        if name in ("dct", "scan"):
            defaults["demo_frames"] = 24
    return config_cls(**{**defaults, **overrides})


def make_policy(name: str, config: PolicyConfig | dict | None = None, **overrides: Any) -> DCPolicy:
    """A freshly initialised policy; `config` defaults to the paper profile, `overrides` replace fields."""
    _check_name(name)
    config_cls, target = POLICIES[name]
    if config is None:
        config = policy_config(name, "paper", **overrides)
    elif isinstance(config, dict):
        config = config_cls.from_dict({**config, **overrides})
    else:
        if not isinstance(config, config_cls):
            raise ValueError(f"config of type {type(config).__name__}: policy {name!r} needs a {config_cls.__name__}")
        if overrides:
            config = config_cls.from_dict({**config.to_dict(), **overrides})
    module, cls = target.split(":")
    return getattr(importlib.import_module(module), cls)(config)


def load_policy(path: Path | str, name: str | None = None, map_location: str = "cpu") -> DCPolicy:
    """A policy from a checkpoint of `train_policy` (or `save_policy`), in eval mode."""
    from aed_models.checkpoint import CheckpointError, load_checkpoint

    ckpt = load_checkpoint(path, family=FAMILY, name=name, map_location=map_location)
    if ckpt.name not in POLICIES:
        raise CheckpointError(f"{path}: policy {ckpt.name!r} is not registered; known: {', '.join(POLICIES)}")
    try:
        policy = make_policy(ckpt.name, ckpt.config)
        policy.load_state_dict(ckpt.state_dict)
    except (ValueError, RuntimeError, TypeError) as e:
        raise CheckpointError(f"{path}: does not fit policy {ckpt.name!r}: {e}") from e
    policy.checkpoint_extra = ckpt.extra  # provenance: training config and environments
    policy.checkpoint_sha256 = ckpt.sha256
    return policy.eval()


def save_policy(path: Path | str, policy: DCPolicy, extra: dict | None = None) -> str:
    """Write `policy` (config + weights + action stats) as a checkpoint; returns its sha256."""
    from aed_models.checkpoint import save_checkpoint

    return save_checkpoint(path, family=FAMILY, name=policy.name, config=policy.config.to_dict(),
                           state_dict=policy.state_dict(), extra=extra)  # fmt: skip


__all__ = ["FAMILY", "POLICIES", "PROFILES", "DCTConfig", "NaiveDCConfig", "PolicyConfig", "SCANConfig",
           "load_policy", "make_policy", "policy_config", "save_policy"]  # fmt: skip

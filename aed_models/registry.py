"""One registry shape for policies and detectors: a name, its config class and its model class.

A model lives in `<package>/<name>/configuration_<name>.py` (the config, torch-free) and
`<package>/<name>/modeling_<name>.py` (the model); the registry lists each name once with the two
class names, imports them on demand and names the model class after its key. Configs own their
`preset(profile)` and `recipe(profile, task)`; checkpoints store `config.to_dict()`.
"""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path
from typing import Any

from aed_models.recipe import Recipe


class UnknownModelError(ValueError):
    """A name, config or checkpoint that no registered model of the family fits."""


@dataclasses.dataclass(frozen=True)
class ModelRegistry:
    """The models of one checkpoint family (`policy` or `detector`) in one package."""

    family: str
    package: str
    classes: dict[str, tuple[str, str]]  # name -> (config class, model class)

    def __iter__(self):
        return iter(self.classes)

    def __contains__(self, name: object) -> bool:
        return name in self.classes

    def __len__(self) -> int:
        return len(self.classes)

    def check(self, name: str) -> str:
        if name not in self.classes:
            raise UnknownModelError(
                f"unknown {self.family} {name!r}; known: {', '.join(self.classes)}"
            )
        return name

    def config_type(self, name: str) -> type:
        module = importlib.import_module(f"{self.package}.{self.check(name)}.configuration_{name}")
        return getattr(module, self.classes[name][0])

    def model_type(self, name: str) -> type:
        module = importlib.import_module(f"{self.package}.{self.check(name)}.modeling_{name}")
        model_cls = getattr(module, self.classes[name][1])
        model_cls.name = name
        return model_cls

    def preset(self, name: str, profile: str = "mini", **overrides: Any) -> Any:
        """The config of `name` at a profile's sizes, with `overrides` replacing fields."""
        config = self.config_type(name).preset(profile)
        return self.replace(name, config, **overrides) if overrides else config

    def recipe(self, name: str, profile: str, task: str) -> Recipe:
        """How `name` trains on `task` under a profile."""
        return self.config_type(name).recipe(profile, task)

    def replace(self, name: str, config: Any, **overrides: Any) -> Any:
        known = {f.name for f in dataclasses.fields(config)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise UnknownModelError(
                f"{name}: unknown config fields {unknown}; known {sorted(known)}"
            )
        return dataclasses.replace(config, **overrides)

    def config_from_dict(self, name: str, values: dict[str, Any]) -> Any:
        """Rebuild a config from its `to_dict()` form (unknown keys refused, missing ones
        default); a config class may define `upgrade_dict(values)` for older checkpoints."""
        config_cls = self.config_type(name)
        upgrade = getattr(config_cls, "upgrade_dict", None)
        values = upgrade(values) if upgrade is not None else values
        known = {f.name for f in dataclasses.fields(config_cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise UnknownModelError(
                f"{name}: config has unknown fields {unknown}; known {sorted(known)}"
            )
        return config_cls(**values)

    def make(self, name: str, config: Any = None, **overrides: Any) -> Any:
        """A freshly initialised model; `config` defaults to the mini preset."""
        config_cls = self.config_type(name)
        if config is None:
            config = config_cls.preset("mini")
        elif isinstance(config, dict):
            config = self.config_from_dict(name, config)
        elif not isinstance(config, config_cls):
            raise UnknownModelError(
                f"config of type {type(config).__name__}: {self.family} {name!r} needs a "
                f"{config_cls.__name__}"
            )
        if overrides:
            config = self.replace(name, config, **overrides)
        return self.model_type(name)(config)

    def save(self, path: Path | str, model: Any, extra: dict[str, Any] | None = None) -> str:
        """Write `model` (its name, config and weights) as a checkpoint; returns its sha256."""
        from aed_models.checkpoint import save_checkpoint

        return save_checkpoint(
            path,
            family=self.family,
            name=model.name,
            config=model.config.to_dict(),
            state_dict=model.state_dict(),
            extra=extra,
        )

    def load(self, path: Path | str, name: str | None = None, map_location: str = "cpu") -> Any:
        """A model from its checkpoint, in eval mode, with `checkpoint_extra` (provenance) and
        `checkpoint_sha256`; `name`, when given, must be the checkpoint's."""
        from aed_models.checkpoint import CheckpointError, load_checkpoint

        if name is not None:
            self.check(name)
        ckpt = load_checkpoint(path, family=self.family, name=name, map_location=map_location)
        if ckpt.name not in self.classes:
            raise CheckpointError(
                f"{path}: {self.family} {ckpt.name!r} is not registered; known: "
                f"{', '.join(self.classes)}"
            )
        try:
            model = self.make(ckpt.name, ckpt.config)
            model.load_state_dict(ckpt.state_dict)
        except (ValueError, RuntimeError, TypeError) as e:
            raise CheckpointError(f"{path}: does not fit {self.family} {ckpt.name!r}: {e}") from e
        model.checkpoint_extra = ckpt.extra
        model.checkpoint_sha256 = ckpt.sha256
        return model.eval()

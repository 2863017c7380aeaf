"""Error detectors, looked up by name.

    detector = make_detector("probe", history_dim=policy.history_dim, task_dim=policy.task_dim)
    config = detector_config("dct_ed", "paper")
    detector = load_detector("runs/PressButton/detectors/probe-dct/checkpoint.pt")

Modelling modules are imported only when a detector is built, so importing this package is
cheap (the `aed` command line lists names without loading torch models).
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from aed_models.detectors.base import ErrorDetector

FAMILY = "detector"


@dataclass(frozen=True)
class DetectorEntry:
    """Where a detector's config and model classes live (imported on demand)."""

    package: str
    config_class: str
    model_class: str

    def config_type(self) -> type:
        return getattr(importlib.import_module(f"aed_models.detectors.{self.package}.configuration_{self.package}"), self.config_class)

    def model_type(self) -> type:
        return getattr(importlib.import_module(f"aed_models.detectors.{self.package}.modeling_{self.package}"), self.model_class)


DETECTORS: dict[str, DetectorEntry] = {
    "svdd_ed": DetectorEntry("svdd_ed", "SVDDEDConfig", "SVDDED"),
    "taskemb_ed": DetectorEntry("taskemb_ed", "TaskEmbEDConfig", "TaskEmbED"),
    "lstm_ed": DetectorEntry("lstm_ed", "LSTMEDConfig", "LSTMED"),
    "dct_ed": DetectorEntry("dct_ed", "DCTEDConfig", "DCTED"),
    "probe": DetectorEntry("probe", "ProbeConfig", "Probe"),
    "rnd_oe": DetectorEntry("rnd_oe", "RNDOEConfig", "RNDOE"),
}

# Parameter counts in the paper's attribute table (rnd_oe is not in the paper).
PAPER_PARAMETERS: dict[str, float] = {
    "svdd_ed": 11.31e6,
    "taskemb_ed": 11.52e6,
    "lstm_ed": 11.85e6,
    "dct_ed": 14.49e6,
    "probe": 0.65e6,
}

# Why a count differs from the paper's (printed by `aed models`).
PAPER_NOTES: dict[str, str] = {
    "dct_ed": "0.1% under: the paper does not give DCT's norm and positional-encoding sizes",
    "probe": "sized by the policy's f_h and f_zeta (256; NaiveDC's f_zeta is 512, first + last frame): "
    "LSTM 0.53M + gate 0.07M + task transform f_zeta x 256 + fusion 0.03M; the paper gives no inner widths",
}


def _entry(name: str) -> DetectorEntry:
    if name not in DETECTORS:
        raise ValueError(f"unknown detector {name!r}: known {sorted(DETECTORS)}")
    return DETECTORS[name]


def detector_config(name: str, profile: str = "mini") -> Any:
    """The default config of detector `name` for a profile (`mini`: CPU-sized, `paper`)."""
    return _entry(name).config_type().for_profile(profile)


def make_detector(name: str, config: Any = None, **overrides: Any) -> ErrorDetector:
    """A freshly initialised detector; `overrides` replace config fields (validated)."""
    entry = _entry(name)
    config_type = entry.config_type()
    if config is None:
        config = config_type()
    elif isinstance(config, dict):
        config = config_from_dict(name, config)
    elif not isinstance(config, config_type):
        raise TypeError(f"config of type {type(config).__name__} for {name!r}: expected {config_type.__name__}")
    if overrides:
        known = {f.name for f in dataclasses.fields(config_type)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"{name}: unknown config fields {unknown}; known {sorted(known)}")
        config = dataclasses.replace(config, **overrides)
    return entry.model_type()(config)


def config_from_dict(name: str, values: dict[str, Any]) -> Any:
    """Rebuild a detector's config dataclass from its `asdict` form (unknown keys refused)."""
    config_type = _entry(name).config_type()
    known = {f.name for f in dataclasses.fields(config_type)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"{name}: config has unknown fields {unknown}; known {sorted(known)}")
    return config_type(**values)


def save_detector(path: Path | str, detector: ErrorDetector, extra: dict[str, Any] | None = None) -> str:
    """Write a detector checkpoint (family `detector`, its name, config, weights); returns sha256."""
    from aed_models.checkpoint import save_checkpoint

    return save_checkpoint(path, family=FAMILY, name=detector.name, config=detector.config_dict(),
                           state_dict=detector.state_dict(), extra=extra)  # fmt: skip


def load_detector(path: Path | str, name: str | None = None) -> ErrorDetector:
    """A detector from its checkpoint, in eval mode; `name` (when given) must match the file's.

    The checkpoint's `extra` (task, policy name and sha256, epoch...) is kept as
    `detector.checkpoint_extra`.

    Raises:
        CheckpointError: missing / corrupt file, not a detector, or a detector of another name.
    """
    from aed_models.checkpoint import CheckpointError, load_checkpoint

    if name is not None:
        _entry(name)
    ckpt = load_checkpoint(path, family=FAMILY, name=name)
    if ckpt.name not in DETECTORS:
        raise CheckpointError(f"{path}: a detector {ckpt.name!r} unknown here; known {sorted(DETECTORS)}")
    try:
        detector = make_detector(ckpt.name, config_from_dict(ckpt.name, ckpt.config))
        detector.load_state_dict(ckpt.state_dict)
    except (TypeError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"{path}: {ckpt.name} checkpoint does not fit its model: {e}") from e
    detector.checkpoint_extra = ckpt.extra
    detector.checkpoint_sha256 = ckpt.sha256
    return detector.eval()


__all__ = ["DETECTORS", "PAPER_NOTES", "PAPER_PARAMETERS", "detector_config", "load_detector", "make_detector", "save_detector"]

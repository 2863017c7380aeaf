"""Error detectors, looked up by name.

    detector = make_detector("probe", history_dim=policy.history_dim, task_dim=policy.task_dim)
    config = DETECTORS.preset("dct_ed", "paper")
    recipe = DETECTORS.recipe("dct_ed", "mini", "PressButton")
    detector = load_detector("runs/PressButton/detectors/probe-dct/detector.pt")

Modelling modules are imported only when a detector is built, so importing this package is
cheap (the `aed` command line lists names without loading torch models).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from aed_models.registry import ModelRegistry

if TYPE_CHECKING:
    from aed_models.detectors.base import ErrorDetector

DETECTORS = ModelRegistry(
    family="detector",
    package="aed_models.detectors",
    classes={
        "svdd_ed": ("SVDDEDConfig", "SVDDED"),
        "taskemb_ed": ("TaskEmbEDConfig", "TaskEmbED"),
        "lstm_ed": ("LSTMEDConfig", "LSTMED"),
        "dct_ed": ("DCTEDConfig", "DCTED"),
        "probe": ("ProbeConfig", "Probe"),
        "rnd_oe": ("RNDOEConfig", "RNDOE"),
    },
)
FAMILY = DETECTORS.family

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
    "probe": "sized by the policy's f_h and f_zeta (256; NaiveDC's f_zeta is 512, first + last "
    "frame): "
    "LSTM 0.53M + gate 0.07M + task transform f_zeta x 256 + fusion 0.03M; the paper gives no "
    "inner widths",
}


def requires_policy(name: str) -> bool:
    """Whether detector `name` reads a frozen policy's features (trained once per policy)."""
    return DETECTORS.model_type(name).requires_policy


def make_detector(name: str, config: Any = None, **overrides: Any) -> ErrorDetector:
    """A freshly initialised detector; `config` defaults to the mini preset, `overrides` replace
    fields."""
    return DETECTORS.make(name, config, **overrides)


def save_detector(
    path: Path | str, detector: ErrorDetector, extra: dict[str, Any] | None = None
) -> str:
    """Write a detector checkpoint (family `detector`, its name, config, weights); returns
    sha256."""
    return DETECTORS.save(path, detector, extra)


def load_detector(path: Path | str, name: str | None = None) -> ErrorDetector:
    """A detector from its checkpoint, in eval mode, with `checkpoint_extra` (task, policy name
    and sha256, epoch...); `name`, when given, must be the file's (else `CheckpointError`)."""
    return DETECTORS.load(path, name)


__all__ = [
    "DETECTORS",
    "PAPER_NOTES",
    "PAPER_PARAMETERS",
    "load_detector",
    "make_detector",
    "requires_policy",
    "save_detector",
]

"""Shared neural-network blocks of the learners: per-frame RGB-D encoders, attention.

`VisualHeadConfig` imports without torch; the modules load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from aed_models.nn.config import VisualHeadConfig

_LAZY = {
    "VisualHead": "aed_models.nn.encoders",
    "build_visual_head": "aed_models.nn.encoders",
    "check_sequences": "aed_models.nn.batch",
    "encode_frames": "aed_models.nn.encoders",
    "lstm_step": "aed_models.nn.recurrent",
    "mlp": "aed_models.nn.mlp",
}

__all__ = ["VisualHeadConfig", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""The one post-processing of detector scores, shared by batched scoring and online monitoring.

A detector's `score` and `step` give per-frame outputs. A detector without memory
(`ErrorDetector.memoryless`: SVDDED, TaskEmbED, RND-OE) scores each frame alone, yet failure
labels run from the error's onset to the end: only a detector with memory can learn that an
error persists. The protocol therefore reads a memoryless detector's running maximum, batched
(`postprocess`) and online (`OnlinePostprocess`, one float of state) alike.
"""

from __future__ import annotations

from typing import Any

import torch


def running_max(scores: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, T) per-frame scores -> their maximum over each rollout's frames so far (0 on
    padding)."""
    return torch.cummax(scores * mask, dim=1).values * mask


def postprocess(detector: Any, scores: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The protocol's (B, T) scores from a detector's per-frame `score` output."""
    return running_max(scores, mask) if detector.memoryless else scores


class OnlinePostprocess:
    """`postprocess` one frame at a time: `reset()` per rollout, then one call per `step`."""

    def __init__(self, detector: Any):
        self.memoryless = bool(detector.memoryless)
        self._max: float | None = None

    def reset(self) -> None:
        self._max = None

    def __call__(self, score: float) -> float:
        if not self.memoryless:
            return score
        self._max = score if self._max is None else max(self._max, score)
        return self._max

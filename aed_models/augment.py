"""Rollout augmentation (paper, "Rollout Augmentation"): keep / drop / swap / copy frames.

Agent rollouts are collected with the agent's optimal policy, so a trained policy's rollouts
differ from them in pace and smoothness. Walking through a rollout and, frame by frame,
keeping it (p 0.3), dropping it (0.3: a speed-up), swapping it with the next one (0.2: a
jerky motion) or repeating it (0.2: a slow-down) dilutes that difference. The transform
works on frame *indices*, so frames, labels, actions and any per-frame array stay aligned:
every output position carries the frame and the label of the same source index.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

OPS = ("keep", "drop", "swap", "copy")


@dataclass(frozen=True)
class RolloutAugment:
    """A seeded, switchable frame-sequence augmentation.

    Args:
        p_keep, p_drop, p_swap, p_copy: probabilities of the four operations (paper:
            0.3 / 0.3 / 0.2 / 0.2); they must sum to 1.
        enabled: False makes the transform the identity (ablations, evaluation).
    """

    p_keep: float = 0.3
    p_drop: float = 0.3
    p_swap: float = 0.2
    p_copy: float = 0.2
    enabled: bool = True

    def __post_init__(self) -> None:
        for name in ("p_keep", "p_drop", "p_swap", "p_copy"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}={value}: must be in [0, 1]")
        total = self.p_keep + self.p_drop + self.p_swap + self.p_copy
        if abs(total - 1.0) > 1e-6:
            raise ValueError(f"p_keep + p_drop + p_swap + p_copy = {total}: must be 1")

    @property
    def probs(self) -> np.ndarray:
        return np.array([self.p_keep, self.p_drop, self.p_swap, self.p_copy])

    def indices(self, length: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """Source frame index of every output frame (int64, never empty for length >= 1).

        A swap exchanges frame i with frame i + 1 and consumes both (the last frame, having
        no successor, is kept). If every frame was dropped, the first one is kept.
        """
        if length < 0:
            raise ValueError(f"length={length}: must be >= 0")
        if not self.enabled or length == 0:
            return np.arange(length, dtype=np.int64)
        rng = np.random.default_rng(rng)
        ops = rng.choice(len(OPS), size=length, p=self.probs)
        out: list[int] = []
        i = 0
        while i < length:
            op = OPS[ops[i]]
            if op == "keep" or (op == "swap" and i + 1 == length):
                out.append(i)
            elif op == "copy":
                out += [i, i]
            elif op == "swap":
                out += [i + 1, i]
                i += 1
            i += 1
        return np.asarray(out or [0], dtype=np.int64)

    def __call__(
        self, *arrays: Any, rng: np.random.Generator | int | None = None
    ) -> tuple[Any, ...]:
        """Apply one draw to several per-frame arrays (numpy or torch) of the same length.

        `augment(frames, labels, rng=seed)` returns `(frames[idx], labels[idx])`.
        """
        if not arrays:
            return ()
        length = len(arrays[0])
        if any(len(a) != length for a in arrays):
            raise ValueError(
                f"arrays of different lengths {[len(a) for a in arrays]}: not per-frame"
            )
        idx = self.indices(length, rng)
        return tuple(_take(a, idx) for a in arrays)


def _take(array: Any, idx: np.ndarray) -> Any:
    if hasattr(array, "index_select"):  # torch
        import torch

        return array.index_select(0, torch.as_tensor(idx, device=array.device))
    return array[idx]

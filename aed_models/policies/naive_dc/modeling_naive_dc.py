"""NaiveDC: f_zeta = mean over demonstrations of [f(first frame), f(last frame)] (no attention)."""

from __future__ import annotations

import torch

from aed_models.policies.base import DCPolicy
from aed_models.policies.naive_dc.configuration_naive_dc import NaiveDCConfig


class NaiveDCPolicy(DCPolicy):
    """f_h[t] = the visual feature of frame t; f_zeta is constant over the rollout (2 x visual
    dim)."""

    def __init__(self, config: NaiveDCConfig):
        d = config.visual.out_dim
        super().__init__(config, history_dim=d, task_dim=2 * d)

    def encode_demos(
        self, frames: torch.Tensor, mask: torch.Tensor, proprio: torch.Tensor | None
    ) -> torch.Tensor:
        lengths = mask.sum(1)
        rows = torch.arange(len(frames), device=frames.device)
        ends = torch.stack(
            [frames[:, 0], frames[rows, lengths - 1]], dim=1
        )  # only 2 frames per demo
        if proprio is not None:
            proprio = torch.stack([proprio[:, 0], proprio[rows, lengths - 1]], dim=1)
        f = self.embed(ends, proprio=proprio)
        return f.flatten(1).mean(0)  # (2 d,)

    def sequence(
        self, f: torch.Tensor, mask: torch.Tensor, memory: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return f, memory.expand(*f.shape[:2], -1)

    def init_state(self, memory: torch.Tensor) -> None:
        return None

    def step(
        self, f_t: torch.Tensor, memory: torch.Tensor, state: None
    ) -> tuple[torch.Tensor, torch.Tensor, None]:
        return f_t, memory[None], None

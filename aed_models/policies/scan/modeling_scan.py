"""SCAN: stage-conscious attention from the rollout to each demonstration, averaged over them.

An LSTM (one layer, unidirectional) runs over the rollout's visual features; its output at t
is the history feature f_h[t] and the query that attends, separately in each demonstration,
over that demonstration's frames (padding masked), so each demonstration contributes the
frames of the stage the rollout is in. The attended frames are averaged over the
demonstrations into f_zeta[t]. The paper, too, uses a standard LSTM rather than SCAN's own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from aed_models.nn.recurrent import lstm_step
from aed_models.policies.base import DCPolicy
from aed_models.policies.scan.configuration_scan import SCANConfig


@dataclass
class DemoMemory:
    keys: torch.Tensor  # (N, L, A)
    values: torch.Tensor  # (N, L, D)
    mask: torch.Tensor  # (N, L)


class SCANPolicy(DCPolicy):
    def __init__(self, config: SCANConfig):
        d = config.visual.out_dim
        super().__init__(config, history_dim=config.lstm_hidden, task_dim=d)
        self.lstm = nn.LSTM(d, config.lstm_hidden, num_layers=1, batch_first=True)
        self.query = nn.Linear(config.lstm_hidden, config.attention_dim)
        self.key = nn.Linear(d, config.attention_dim)
        self.value = nn.Linear(d, d)
        self.scale = 1.0 / math.sqrt(config.attention_dim)

    def encode_demos(
        self, frames: torch.Tensor, mask: torch.Tensor, proprio: torch.Tensor | None
    ) -> DemoMemory:
        f = self.embed(frames, mask, proprio)
        return DemoMemory(self.key(f), self.value(f), mask)

    def attend(self, history: torch.Tensor, memory: DemoMemory) -> torch.Tensor:
        """history (B, T, H) -> task embedding (B, T, D): per-demo attention, then the mean."""
        scores = torch.einsum("bta,nla->btnl", self.query(history), memory.keys) * self.scale
        scores = scores.masked_fill(~memory.mask, float("-inf"))
        weights = torch.softmax(scores, dim=-1)
        return torch.einsum("btnl,nld->btnd", weights, memory.values).mean(dim=2)

    def sequence(
        self, f: torch.Tensor, mask: torch.Tensor, memory: DemoMemory
    ) -> tuple[torch.Tensor, torch.Tensor]:
        history, _ = self.lstm(f)  # padding sits after the valid steps, so they are unaffected
        return history, self.attend(history, memory)

    def init_state(self, memory: DemoMemory) -> None:
        return None  # nn.LSTM starts from zeros

    def step(self, f_t: torch.Tensor, memory: DemoMemory, state):
        history, state = lstm_step(self.lstm, f_t, state)
        return history, self.attend(history[:, None], memory)[:, 0], state

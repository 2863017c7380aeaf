"""RND-OE: random network distillation on the frozen policy's history features f_h.

A fixed, randomly initialised target MLP maps each f_h[t] to a vector; a predictor MLP learns
to reproduce it on the frames of *successful* rollouts only. Where the policy's internal state
looks like the successes it was fitted on, the prediction error is small; unfamiliar states (a
behaviour error, a new failure mode) give a large error. No failure data is needed, and every
frame is scored on its own (O(1) per step).

Input normalisation (as in Burda et al.'s RND): f_h is unit-normalised, then whitened per
dimension by the running mean and variance of the training frames and clipped to +-5. Without
it the target is near constant: a policy's f_h of different frames point in almost the same
direction, the random target maps them all to nearly one vector, and the predictor learns that
vector within a few epochs (training error ~1e-6) and nothing about the frames.

Score normalisation: the raw error is divided by a running mean of the training error on
success frames (buffers saved with the weights), so a score of ~1 means "as familiar as the
training successes" (held-out successes score somewhat higher: the predictor fits what it
saw) and scores of detectors trained on different policies or tasks are on a
comparable scale. It is a distance (`output = "distance"`), unbounded above.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from aed_models.detectors.base import Batch, ErrorDetector, rollout_mask, split_features
from aed_models.detectors.rnd_oe.configuration_rnd_oe import RNDOEConfig


def mlp(in_dim: int, hidden: int, out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, out))


class RNDOE(ErrorDetector):
    name = "rnd_oe"
    requires_policy = True
    output = "distance"
    trains_on = "successes"

    def __init__(self, config: RNDOEConfig | None = None):
        config = config or RNDOEConfig()
        super().__init__(config)
        c = config
        self.target = mlp(c.history_dim, c.hidden_dim, c.out_dim)
        self.target.requires_grad_(False)
        self.predictor = mlp(c.history_dim, c.hidden_dim, c.out_dim)
        # bias-corrected running mean of the training error (as Adam's moments): ema / weight
        self.register_buffer("error_ema", torch.zeros(()))
        self.register_buffer("ema_weight", torch.zeros(()))
        # running input statistics (Chan et al.'s parallel update): count, mean, variance
        self.register_buffer("input_count", torch.zeros(()))
        self.register_buffer("input_mean", torch.zeros(c.history_dim))
        self.register_buffer("input_var", torch.ones(c.history_dim))
        self._started = False

    def _unit(self, history: torch.Tensor) -> torch.Tensor:
        if history.shape[-1] != self.config.history_dim:
            raise ValueError(f"history features of size {history.shape[-1]}: built for history_dim={self.config.history_dim}")
        return history / history.norm(dim=-1, keepdim=True).clamp(min=self.config.norm_eps)

    @torch.no_grad()
    def update_input_stats(self, unit: torch.Tensor) -> None:
        """Merge a (N, Dh) batch of unit features into the running mean and variance."""
        n = float(unit.shape[0])
        if n == 0:
            return
        mean, var = unit.mean(0), unit.var(0, unbiased=False)
        total = self.input_count + n
        delta = mean - self.input_mean
        m2 = self.input_var * self.input_count + var * n + delta.pow(2) * self.input_count * n / total
        self.input_mean.add_(delta * n / total)
        self.input_var.copy_(m2 / total)
        self.input_count.copy_(total)

    def _whiten(self, unit: torch.Tensor) -> torch.Tensor:
        std = self.input_var.sqrt().clamp(min=self.config.norm_eps)
        return ((unit - self.input_mean) / std).clamp(-self.config.input_clip, self.config.input_clip)

    def errors(self, history: torch.Tensor) -> torch.Tensor:
        """(..., Dh) -> raw squared prediction errors (...), averaged over output cells."""
        x = self._whiten(self._unit(history))
        with torch.no_grad():
            target = self.target(x)
        return (self.predictor(x) - target).pow(2).mean(-1)

    def loss(self, batch: Batch, policy_features: Any = None) -> tuple[torch.Tensor, dict[str, float]]:
        """Mean prediction error over the valid frames of successful rollouts."""
        rollouts = batch["rollouts"]
        mask = rollout_mask(rollouts)
        if "is_failure" in rollouts:
            mask = mask & ~rollouts["is_failure"].bool()[:, None]
        if not mask.any():
            raise ValueError("rnd_oe trains on successes: the batch has no successful rollout frame")
        history, _ = split_features(policy_features)
        if self.training:
            self.update_input_stats(self._unit(history[mask]))
        loss = self.errors(history)[mask].mean()
        if self.training:
            m = self.config.scale_momentum
            self.error_ema.mul_(m).add_((1.0 - m) * loss.detach())
            self.ema_weight.mul_(m).add_(1.0 - m)
        return loss, {"rnd": float(loss.detach()), "scale": float(self.error_scale)}

    @property
    def error_scale(self) -> torch.Tensor:
        """Running mean training error on successes (1 before any training step)."""
        if self.ema_weight <= 0:
            return torch.ones((), device=self.ema_weight.device)
        return (self.error_ema / self.ema_weight).clamp(min=1e-12)

    def _normalised(self, history: torch.Tensor) -> torch.Tensor:
        return self.errors(history) / self.error_scale

    @torch.no_grad()
    def score(self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None) -> torch.Tensor:
        mask = rollout_mask(rollouts)
        history, _ = split_features(policy_features)
        return self._normalised(history) * mask

    def reset(self, demos: Batch | None = None) -> None:
        self._started = True

    @torch.no_grad()
    def step(self, frame: torch.Tensor | None = None, policy_features: tuple[torch.Tensor, torch.Tensor] | None = None) -> float:
        if not self._started:
            raise RuntimeError("rnd_oe: call reset(demos) before step()")
        f_h, _ = split_features(policy_features)
        return float(self._normalised(f_h.reshape(1, -1))[0])

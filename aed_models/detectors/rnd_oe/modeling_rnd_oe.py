"""RND-OE: random network distillation on the frozen policy's history features f_h.

A predictor learns a fixed random target's output on the f_h of successful rollouts only, so
its error is small where the policy's state looks like those successes: no failure data is
needed. Inputs are unit-normalised, whitened and clipped (as Burda et al.'s RND), else the
target is near constant. The per-frame error is divided by the training successes' mean error
in the step's time bin and by the rollout's own first `baseline_steps` frames, so what is left
is the drift since the start, not how new the environment is. Online a step is O(1).
"""

from __future__ import annotations

from typing import Any

import torch

from aed_models.detectors.base import (
    Batch,
    ErrorDetector,
    rollout_mask,
    split_features,
    steps_of,
)
from aed_models.detectors.rnd_oe.configuration_rnd_oe import RNDOEConfig
from aed_models.nn.mlp import mlp


class RNDOE(ErrorDetector):
    requires_policy = True
    output = "distance"
    trains_on = "successes"
    memoryless = True

    def __init__(self, config: RNDOEConfig | None = None):
        config = config or RNDOEConfig()
        super().__init__(config)
        c = config
        self.target = mlp([c.history_dim, c.hidden_dim, c.hidden_dim], c.out_dim)
        self.target.requires_grad_(False)
        self.predictor = mlp([c.history_dim, c.hidden_dim, c.hidden_dim], c.out_dim)
        # bias-corrected running means of the training error (as Adam's moments): ema / weight,
        # over all success frames and per time bin of success frames
        self.register_buffer("error_ema", torch.zeros(()))
        self.register_buffer("ema_weight", torch.zeros(()))
        self.register_buffer("bin_ema", torch.zeros(c.num_time_bins))
        self.register_buffer("bin_weight", torch.zeros(c.num_time_bins))
        # running input statistics (Chan et al.'s parallel update): count, mean, variance
        self.register_buffer("input_count", torch.zeros(()))
        self.register_buffer("input_mean", torch.zeros(c.history_dim))
        self.register_buffer("input_var", torch.ones(c.history_dim))
        self._step_scale: torch.Tensor | None = None  # time_scale, fixed at reset(); None before
        self._t, self._baseline_sum = 0, 0.0

    def _unit(self, history: torch.Tensor) -> torch.Tensor:
        if history.shape[-1] != self.config.history_dim:
            raise ValueError(
                f"history features of size {history.shape[-1]}: "
                f"built for history_dim={self.config.history_dim}"
            )
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
        m2 = (
            self.input_var * self.input_count
            + var * n
            + delta.pow(2) * self.input_count * n / total
        )
        self.input_mean.add_(delta * n / total)
        self.input_var.copy_(m2 / total)
        self.input_count.copy_(total)

    def _whiten(self, unit: torch.Tensor) -> torch.Tensor:
        std = self.input_var.sqrt().clamp(min=self.config.norm_eps)
        return ((unit - self.input_mean) / std).clamp(
            -self.config.input_clip, self.config.input_clip
        )

    def errors(self, history: torch.Tensor) -> torch.Tensor:
        """(..., Dh) -> raw squared prediction errors (...), averaged over output cells."""
        x = self._whiten(self._unit(history))
        with torch.no_grad():
            target = self.target(x)
        return (self.predictor(x) - target).pow(2).mean(-1)

    def loss(
        self, batch: Batch, policy_features: Any = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Mean prediction error over the valid frames of successful rollouts."""
        rollouts = batch["rollouts"]
        mask = rollout_mask(rollouts)
        if "is_failure" in rollouts:
            mask = mask & ~rollouts["is_failure"].bool()[:, None]
        if not mask.any():
            raise ValueError(
                "rnd_oe trains on successes: the batch has no successful rollout frame"
            )
        history, _ = split_features(policy_features)
        if self.training:
            self.update_input_stats(self._unit(history[mask]))
        errors = self.errors(history)
        loss = errors[mask].mean()
        if self.training:
            self._update_scales(errors.detach()[mask], self._bins(steps_of(rollouts, mask)[mask]))
        return loss, {"rnd": float(loss.detach()), "scale": float(self.error_scale)}

    @torch.no_grad()
    def _update_scales(self, errors: torch.Tensor, bins: torch.Tensor) -> None:
        """One momentum step of the overall and the per-bin mean training errors."""
        m = self.config.scale_momentum
        self.error_ema.mul_(m).add_((1.0 - m) * errors.mean())
        self.ema_weight.mul_(m).add_(1.0 - m)
        sums = torch.zeros_like(self.bin_ema).index_add_(0, bins, errors)
        counts = torch.zeros_like(self.bin_ema).index_add_(0, bins, torch.ones_like(errors))
        seen = counts > 0
        self.bin_ema[seen] = m * self.bin_ema[seen] + (1.0 - m) * sums[seen] / counts[seen]
        self.bin_weight[seen] = m * self.bin_weight[seen] + (1.0 - m)

    def _bins(self, steps: torch.Tensor) -> torch.Tensor:
        if not self.config.time_bin:
            return torch.zeros_like(steps)
        return (steps // self.config.time_bin).clamp(max=self.config.num_time_bins - 1)

    @property
    def error_scale(self) -> torch.Tensor:
        """Running mean training error on successes (1 before any training step)."""
        if self.ema_weight <= 0:
            return torch.ones((), device=self.ema_weight.device)
        return (self.error_ema / self.ema_weight).clamp(min=1e-12)

    @property
    def time_scale(self) -> torch.Tensor:
        """(num_time_bins,) mean training error on successes per bin; a bin no training frame
        reached takes the bin before it (the overall mean before the first seen bin)."""
        scale = self.error_scale.expand(self.config.num_time_bins).clone()
        seen = (self.bin_weight > 0).tolist()
        for b in range(len(scale)):
            if seen[b]:
                scale[b] = (self.bin_ema[b] / self.bin_weight[b]).clamp(min=1e-12)
            elif b > 0:
                scale[b] = scale[b - 1]
        return scale

    def calibrated(self, history: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        """Prediction errors (...) divided by the training successes' mean error at their step."""
        return self.errors(history) / self.time_scale[self._bins(steps)]

    @torch.no_grad()
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        mask = rollout_mask(rollouts)
        history, _ = split_features(policy_features)
        score = self.calibrated(history, steps_of(rollouts, mask)) * mask
        k = self.config.baseline_steps
        if k:
            positions = torch.arange(mask.shape[1], device=mask.device)
            first = positions.clamp(max=k - 1)  # the baseline's last frame so far
            baseline = torch.cumsum(score, dim=1)[:, first] / (first + 1)
            score = score / baseline.clamp(min=1e-12)
        return score * mask

    def reset(self, demos: Batch | None = None) -> None:
        self._step_scale = self.time_scale
        self._t, self._baseline_sum = 0, 0.0

    @torch.no_grad()
    def step(
        self,
        frame: torch.Tensor | None = None,
        policy_features: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> float:
        self._require_reset(self._step_scale)
        f_h, _ = split_features(policy_features)
        bin_ = int(self._bins(torch.tensor(self._t)))
        score = float(self.errors(f_h.reshape(1, -1))[0] / self._step_scale[bin_])
        k = self.config.baseline_steps
        if k:
            if self._t < k:
                self._baseline_sum += score
            score = score / max(self._baseline_sum / min(self._t + 1, k), 1e-12)
        self._t += 1
        return score

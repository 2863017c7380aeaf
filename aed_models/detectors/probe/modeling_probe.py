"""PrObe (paper, "Pattern Observer"): error detection from the frozen policy's features.

    f_h --unit norm--> u --gate: sigmoid(FC(u))--> sign(u) * gate --IN--> f_p --LSTM--> flow
    f_zeta --IN--> FC --> tanh --> task'
    [flow, task'] --FC + ReLU--> logit embedding --FC--> logit --sigmoid--> error probability

"Instance norm" of one feature vector: PrObe sees one vector per time step, so IN here
normalises over the feature dimension of each time step separately (zero mean, unit
variance across the D cells, no affine part); it never mixes time steps, so online and
offline agree.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from aed_models.detectors.base import Batch, ErrorDetector, rollout_mask, split_features
from aed_models.detectors.probe.configuration_probe import ProbeConfig
from aed_models.losses import masked_bce, pattern_l1, sample_triplets, temporal_triplet_loss
from aed_models.nn.recurrent import lstm_step


def feature_norm(x: torch.Tensor, eps: float) -> torch.Tensor:
    """Instance norm of each feature vector over its last dimension (see module docstring)."""
    return F.layer_norm(x, x.shape[-1:], eps=eps)


class Probe(ErrorDetector):
    requires_policy = True
    output = "probability"
    trains_on = "both"

    def __init__(self, config: ProbeConfig | None = None):
        config = config or ProbeConfig()
        super().__init__(config)
        c = config
        self.gate = nn.Linear(
            c.history_dim, c.history_dim
        )  # the naive ablation's FC when the extractor is off
        self.flow = nn.LSTM(c.history_dim, c.hidden_dim, batch_first=True)
        self.task_fc = nn.Linear(c.task_dim, c.hidden_dim)
        self.fusion = nn.Linear(2 * c.hidden_dim, c.embed_dim)
        self.classifier = nn.Linear(c.embed_dim, 1)
        self._state: tuple[torch.Tensor, torch.Tensor] | None = None
        self._started = False

    # -- the network --------------------------------------------------------------------------
    def patterns(self, history: torch.Tensor) -> torch.Tensor:
        """f_h (..., Dh) -> pattern features f_p (..., Dh)."""
        eps = self.config.norm_eps
        if not self.config.use_pattern_extractor:
            return feature_norm(self.gate(history), eps)
        unit = history / history.norm(dim=-1, keepdim=True).clamp(min=eps)
        importance = torch.sigmoid(self.gate(unit))
        return feature_norm(torch.sign(unit) * importance, eps)

    def transform_task(self, task: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.task_fc(feature_norm(task, self.config.norm_eps)))

    def head(self, flow: torch.Tensor, task: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(logit embedding, logit) from the pattern flow and the raw task embedding."""
        embedding = torch.relu(self.fusion(torch.cat([flow, self.transform_task(task)], dim=-1)))
        return embedding, self.classifier(embedding).squeeze(-1)

    def forward(self, history: torch.Tensor, task: torch.Tensor) -> dict[str, torch.Tensor]:
        """history (B, T, Dh), task (B, T, Dz) -> patterns, embeddings (B, T, E), logits (B, T)."""
        self._check_dims(history, task)
        patterns = self.patterns(history)
        flow, _ = self.flow(patterns)
        embeddings, logits = self.head(flow, task)
        return {"patterns": patterns, "embeddings": embeddings, "logits": logits}

    def _check_dims(self, history: torch.Tensor, task: torch.Tensor) -> None:
        c = self.config
        if history.shape[-1] != c.history_dim or task.shape[-1] != c.task_dim:
            raise ValueError(
                f"policy features of sizes history {history.shape[-1]}, task {task.shape[-1]}: "
                f"this PrObe was built for history_dim={c.history_dim}, task_dim={c.task_dim}"
            )

    # -- training -----------------------------------------------------------------------------
    def loss(
        self, batch: Batch, policy_features: Any = None, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """lambda_cls L_cls + lambda_pat L_pat + lambda_tem L_tem (see `aed_models.losses`)."""
        c = self.config
        rollouts = batch["rollouts"]
        mask = rollout_mask(rollouts)
        history, task = split_features(policy_features)
        out = self(history, task)
        parts: dict[str, torch.Tensor] = {}
        if c.lambda_cls:
            parts["cls"] = masked_bce(out["logits"], rollouts["labels"], mask)
        if c.lambda_pat:
            parts["pat"] = pattern_l1(out["patterns"], mask)
        if c.lambda_tem:
            triplets = sample_triplets(
                rollouts["labels"], mask, rollouts["is_failure"], c.triplets_per_rollout, generator
            )
            lengths = rollouts.get("lengths", mask.sum(1))
            parts["tem"] = temporal_triplet_loss(
                out["embeddings"], triplets, lengths, c.margin, c.alpha, c.clip
            )
        weights = {"cls": c.lambda_cls, "pat": c.lambda_pat, "tem": c.lambda_tem}
        total = sum(weights[k] * v for k, v in parts.items())
        return total, {k: float(v.detach()) for k, v in parts.items()}

    # -- inference ----------------------------------------------------------------------------
    @torch.no_grad()
    def score(
        self, rollouts: Batch, demos: Batch | None = None, policy_features: Any = None
    ) -> torch.Tensor:
        mask = rollout_mask(rollouts)
        history, task = split_features(policy_features)
        return torch.sigmoid(self(history, task)["logits"]) * mask

    def reset(self, demos: Batch | None = None) -> None:
        """Demonstrations reach PrObe through the policy's task embedding: only the state resets."""
        self._state = None
        self._started = True

    @torch.no_grad()
    def step(
        self,
        frame: torch.Tensor | None = None,
        policy_features: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> float:
        if not self._started:
            raise RuntimeError("probe: call reset(demos) before step()")
        f_h, f_zeta = split_features(policy_features)
        history, task = f_h.reshape(1, 1, -1), f_zeta.reshape(1, 1, -1)
        self._check_dims(history, task)
        flow, self._state = lstm_step(self.flow, self.patterns(history)[:, 0], self._state)
        _, logit = self.head(flow[:, None], task)
        return float(torch.sigmoid(logit))

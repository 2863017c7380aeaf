"""The demonstration-conditioned (DC) policy shared by NaiveDC, DCT and SCAN.

Paper, "Preliminaries": a visual head encodes every frame (rollout and demonstrations), a
task-embedding network turns the demonstrations (and the rollout so far) into f_zeta, and an
actor maps [f_h, f_zeta] to the action: a position delta (3) and a gripper command (1).

Subclasses supply the task-embedding network through four hooks:

- `encode_demos(frames, mask, proprio) -> memory`: everything the task net needs from the
  demonstrations (per-frame features come from `embed`);
- `sequence(f, mask, memory) -> (history, task)`: batched and causal over the rollout;
- `init_state(memory)` and `step(f_t, memory, state) -> (history_t, task_t, state)`: the
  same computation one frame at a time, with per-frame results cached in `state`.

A policy with a target localizer (`config.localizer`, under `mini`) also locates, in the
rollout's first frame, where each of the demonstrations' stages ended, and its actor reads the
offsets from the TCP to those points beside [f_h, f_zeta]; detectors read f_h and f_zeta only.

Actions are learned standardised (the expert's per-axis std is ~0.1: raw, the MSE sits at
the variance and nothing is learned); `act` de-standardises, clips to [-1, 1] and turns the
gripper logit into +1 (open) / -1 (closed).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from aed_models.data import (
    PROPRIO_DIM,
    proprio_from_obs,
    stage_end_points,
    subsample,
    to_frames,
)
from aed_models.nn.batch import check_sequences
from aed_models.nn.encoders import build_visual_head, encode_frames
from aed_models.nn.mlp import mlp
from aed_models.policies.configuration_base import PolicyConfig

if TYPE_CHECKING:
    from aed_models.localizer.modeling_localizer import StageQueries

logger = logging.getLogger(__name__)

ACTION_DIM = 4  # pd_ee_delta_pos: dx, dy, dz in [-1, 1], gripper +1 open / -1 closed
SUBGOAL_SCALE_M = 0.1  # subgoal offsets are learned in units of 10 cm (the reach of a stage)
ENSEMBLE_DECAY = 0.01  # ACT's temporal ensembling: weight exp(-0.01 i), i = 0 the oldest


@dataclass
class PolicyFeatures:
    """What detectors read: f_h (B, T, history_dim) and f_zeta (B, T, task_dim) per rollout step."""

    history: torch.Tensor
    task: torch.Tensor


def ensemble_latest(pos: torch.Tensor, grip: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """ACT's temporal ensemble: the chunks of the last n steps, oldest first, pos (..., n, C, 3)
    and grip (..., n, C, 1) -> the latest step's action, (..., 3) and (..., 1): the mean of what
    each predicted for it (the i-th oldest its element n - 1 - i), weighted exp(-ENSEMBLE_DECAY
    * i), normalised."""
    n = pos.shape[-3]
    rows, ages = torch.arange(n), torch.arange(n - 1, -1, -1)
    weights = torch.exp(-ENSEMBLE_DECAY * torch.arange(n, dtype=pos.dtype, device=pos.device))
    weights = (weights / weights.sum())[:, None]
    return (weights * pos[..., rows, ages, :]).sum(-2), (weights * grip[..., rows, ages, :]).sum(-2)


class Actor(nn.Module):
    """MLP [in, 256, 64] with two parallel heads: position (3) and gripper control (1), for
    each of the `chunk` steps from this one: (..., chunk, 3) and (..., chunk, 1)."""

    def __init__(self, in_dim: int, hidden: tuple[int, ...], chunk: int = 1):
        super().__init__()
        self.chunk = chunk
        self.body = mlp([in_dim, *hidden])
        self.pos = nn.Linear(hidden[-1], 3 * chunk)
        self.grip = nn.Linear(hidden[-1], chunk)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.body(x)
        return self.pos(h).unflatten(-1, (self.chunk, 3)), self.grip(h)[..., None]


class PointerSubgoalHead(nn.Module):
    """Stage-target head that points: a softmax choice among the offsets to the K located
    points (MLP [in, 64, K] on the actor's input) plus a linear residual that starts at 0.

    A linear map from [f_h, f_zeta, offsets] may lean on what TCP and time already explain and
    ignore a located coordinate; a choice among the offsets carries each one through unscaled
    and only has to learn which stage it is in."""

    def __init__(self, in_dim: int, num_targets: int, hidden: int = 64):
        super().__init__()
        self.num_targets = num_targets
        self.select = nn.Sequential(
            nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, num_targets)
        )
        self.residual = nn.Linear(in_dim, 3)
        nn.init.zeros_(self.residual.weight)
        nn.init.zeros_(self.residual.bias)

    def forward(self, actor_input: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """actor_input (..., in_dim), offsets (..., 3K) -> predicted offset (..., 3)."""
        weights = torch.softmax(self.select(actor_input), dim=-1)
        points = offsets.unflatten(-1, (self.num_targets, 3))
        return (weights[..., None] * points).sum(-2) + self.residual(actor_input)


def thin_sequences(
    frames: torch.Tensor, mask: torch.Tensor, proprio: torch.Tensor | None, limit: int
):
    """At most `limit` frames (or features) of each padded sequence, chosen by
    `aed_models.data.subsample` (evenly spread, first and last kept)."""
    lengths = mask.sum(1).tolist()
    if limit == 0 or max(lengths) <= limit:
        return frames, mask, proprio
    idx = torch.zeros(len(lengths), limit, dtype=torch.long, device=mask.device)
    new_mask = torch.zeros(len(lengths), limit, dtype=torch.bool, device=mask.device)
    for row, length in enumerate(lengths):
        kept = torch.from_numpy(subsample(np.arange(length), limit))
        idx[row, : len(kept)] = kept
        new_mask[row, : len(kept)] = True
    rows = torch.arange(len(mask), device=mask.device)[:, None]
    proprio = None if proprio is None else proprio[rows, idx] * new_mask[..., None]
    keep_mask = new_mask.view(*new_mask.shape, *(1,) * (frames.dim() - 2))
    return frames[rows, idx] * keep_mask, new_mask, proprio


def check_proprio(batch: dict, what: str, needed: bool) -> torch.Tensor | None:
    """The group's proprio (B, L, PROPRIO_DIM) when the policy reads it, else None."""
    if not needed:
        return None
    proprio = batch.get("proprio")
    inputs = batch["features"] if "features" in batch else batch["frames"]
    shape = (*inputs.shape[:2], PROPRIO_DIM)
    if proprio is None or tuple(proprio.shape) != shape:
        got = "none" if proprio is None else tuple(proprio.shape)
        raise ValueError(
            f"{what}['proprio']: this policy reads proprioception (config.proprio); "
            f"expected {shape}, got {got}"
        )
    return proprio.float()


class DCPolicy(nn.Module):
    """Visual head + task-embedding network + actor. See the module docstring for the hooks.

    History feature f_h[t]: NaiveDC and DCT, the visual feature of frame t; SCAN, its LSTM
    output at t (what its actor reads). Task embedding f_zeta[t]: NaiveDC, constant over t.
    Online features are inference-mode tensors (read them, do not backpropagate through them).
    """

    name: ClassVar[str] = ""  # the registry key, set by the registry
    camera = "front"

    def __init__(self, config: PolicyConfig, history_dim: int, task_dim: int):
        super().__init__()
        self.config = config
        self.history_dim, self.task_dim = history_dim, task_dim
        self.visual = build_visual_head(config.visual)
        self.proprio_embed = (
            nn.Linear(PROPRIO_DIM, config.visual.out_dim) if config.proprio else None
        )
        self.localizer = None
        located_dim = 0
        if config.localizer is not None:
            from aed_models.localizer.modeling_localizer import TargetLocalizer

            self.localizer = TargetLocalizer(config.localizer)
            located_dim = 3 * config.localizer.num_targets
        self.subgoal_head = None
        self.subgoal_gain = None  # pointer head: per-axis gain from the predicted offset to pos
        head_in = history_dim + task_dim + located_dim
        if config.subgoal_weight > 0 and config.subgoal_head == "pointer":
            self.subgoal_head = PointerSubgoalHead(head_in, config.localizer.num_targets)
            self.subgoal_gain = nn.Parameter(torch.zeros(3))
        elif config.subgoal_weight > 0:
            self.subgoal_head = nn.Linear(head_in, 3)
        self.actor = Actor(
            history_dim + task_dim + located_dim + (3 if self.subgoal_head is not None else 0),
            config.actor_hidden,
            config.action_chunk,
        )
        self.inverse_dynamics = None
        if config.inverse_dynamics:
            d = config.visual.out_dim
            self.inverse_dynamics = nn.Sequential(
                mlp([2 * d, *config.actor_hidden]), nn.Linear(config.actor_hidden[-1], ACTION_DIM)
            )
        self.register_buffer("action_mean", torch.zeros(ACTION_DIM))
        self.register_buffer("action_std", torch.ones(ACTION_DIM))
        self._online: dict[str, Any] | None = None

    def embed(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        proprio: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Per-frame features: frames (B, L, 4, H, W) or (B, 4, H, W) -> (B, L, out_dim) or
        (B, out_dim), the visual head's plus the embedded proprioception. Given the frozen visual
        head's cached features ((B, L, out_dim) or (B, out_dim)) instead of frames, it adds the
        proprioception alone."""
        if frames.dim() <= 3:
            f = frames
        elif frames.dim() == 4:
            f = self.visual(frames)
        else:
            f = encode_frames(self.visual, frames, mask)
        if self.proprio_embed is not None:
            if proprio is None:
                raise ValueError(
                    "this policy reads proprioception (config.proprio) but none was given"
                )
            f = f + self.proprio_embed(proprio.to(f.dtype))
        return f

    # -- task-embedding hooks ------------------------------------------------------------
    def encode_demos(
        self, frames: torch.Tensor, mask: torch.Tensor, proprio: torch.Tensor | None
    ) -> Any:
        raise NotImplementedError

    def sequence(
        self, f: torch.Tensor, mask: torch.Tensor, memory: Any
    ) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def init_state(self, memory: Any) -> Any:
        raise NotImplementedError

    def step(
        self, f_t: torch.Tensor, memory: Any, state: Any
    ) -> tuple[torch.Tensor, torch.Tensor, Any]:
        raise NotImplementedError

    # -- batched ---------------------------------------------------------------------------
    def set_action_stats(self, actions: torch.Tensor) -> None:
        """Per-axis mean and std of the training actions (M, 4); std floored at 1e-3."""
        actions = torch.as_tensor(actions, dtype=torch.float32).reshape(-1, ACTION_DIM)
        if len(actions) < 2:
            raise ValueError(f"set_action_stats: {len(actions)} actions, need at least 2")
        self.action_mean.copy_(actions.mean(0))
        self.action_std.copy_(actions.std(0).clamp_min(1e-3))

    def _features(self, rollouts: dict, demos: dict) -> tuple[torch.Tensor, PolicyFeatures]:
        memory = self.encode_demos(*self.demo_inputs(demos))
        inputs, mask = check_sequences(rollouts, "rollouts")
        f = self.embed(inputs, mask, check_proprio(rollouts, "rollouts", self.config.proprio))
        history, task = self.sequence(f, mask, memory)
        return f, PolicyFeatures(history, task)

    # -- target localizer ------------------------------------------------------------------
    def demo_queries(self, demos: dict) -> StageQueries:
        """The localizer's K stage queries from the demonstrations' first frames and where
        each ended its stages (their `subgoal` targets, unthinned)."""
        frames, mask = demos.get("frames"), demos.get("mask")
        if frames is None or frames.dim() != 5 or mask is None or demos.get("subgoal") is None:
            raise ValueError(
                "demos: this policy locates its targets from the demonstrations' first frames "
                "and stage targets; expected demos['frames'] (N, L, 4, H, W), demos['mask'] "
                "(N, L) and demos['subgoal'] (N, L, 3)"
            )
        k = self.localizer.config.num_targets
        lengths = mask.sum(1).tolist()
        points = torch.stack(
            [stage_end_points(demos["subgoal"][i, :n].cpu(), k) for i, n in enumerate(lengths)]
        ).to(frames.device)
        return self.localizer.queries(frames[:, 0].float(), points)

    def located_offsets(self, located: torch.Tensor, proprio: torch.Tensor) -> torch.Tensor:
        """World points (..., 3K) and proprio (..., 5) -> the offsets from the TCP to each
        point (..., 3K), in units of `SUBGOAL_SCALE_M`."""
        tcp = proprio[..., :3]
        points = located.unflatten(-1, (-1, 3))
        return ((points - tcp[..., None, :]) / SUBGOAL_SCALE_M).flatten(-2)

    def _rollout_located(self, rollouts: dict, demos: dict) -> torch.Tensor | None:
        """(B, T, 3K) located points of each rollout: given (`rollouts['located']`, cached
        for training), or located in each rollout's first frame."""
        if self.localizer is None:
            return None
        _, mask = check_sequences(rollouts, "rollouts")
        located = rollouts.get("located")
        if located is None:
            frames = rollouts.get("frames")
            if frames is None or frames.dim() != 5:
                raise ValueError(
                    "rollouts: this policy locates its targets in the first frame; give "
                    "rollouts['frames'] (B, T, 4, H, W) or rollouts['located'] (B, T, 3K)"
                )
            points = self.localizer.locate(frames[:, 0], self.demo_queries(demos))
            located = points.flatten(1)[:, None].expand(-1, mask.shape[1], -1)
        width = 3 * self.localizer.config.num_targets
        if tuple(located.shape) != (*mask.shape, width):
            raise ValueError(
                f"rollouts['located'] of shape {tuple(located.shape)}: expected "
                f"{(*mask.shape, width)}"
            )
        return located.float()

    def demo_inputs(self, demos: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """The demonstrations' frames, mask and proprio (or None), thinned to
        `config.demo_frames`."""
        frames, mask = check_sequences(demos, "demos")
        return thin_sequences(
            frames,
            mask,
            check_proprio(demos, "demos", self.config.proprio),
            self.config.demo_frames,
        )

    def features(
        self,
        frames: torch.Tensor | None = None,
        mask: torch.Tensor | None = None,
        demos: dict | None = None,
        proprio: torch.Tensor | None = None,
    ):
        """Batched: `features(frames (B, T, 4, H, W), mask (B, T), demos, proprio (B, T, 5))`
        -> PolicyFeatures (`proprio` only for a policy that reads it).

        Online (no arguments): `(f_h (history_dim,), f_zeta (task_dim,))` of the latest `act`.
        """
        if frames is None:
            if self._online is None or self._online.get("history") is None:
                raise RuntimeError("features(): no step yet; call reset(demos) and act(obs) first")
            return self._online["history"], self._online["task"]
        if demos is None:
            raise ValueError("features(frames, mask, demos): demos missing")
        rollouts = (
            {"frames": frames, "mask": mask}
            if proprio is None
            else {"frames": frames, "mask": mask, "proprio": proprio}
        )
        return self._features(rollouts, demos)[1]

    def forward(self, rollouts: dict, demos: dict) -> dict[str, torch.Tensor]:
        """rollouts (B, T, ...) conditioned on the N demos they share -> standardised pos (B, T, 3),
        gripper logit (B, T, 1), both for the `action_chunk` steps from each (`pos_chunk`
        (B, T, C, 3), `grip_chunk` (B, T, C, 1)), history / task features and the per-frame
        features."""
        f, feats = self._features(rollouts, demos)
        located = self._rollout_located(rollouts, demos)
        offsets = None
        if located is not None:
            offsets = self.located_offsets(located, rollouts["proprio"].to(located.device))
        pos, grip, subgoal = self._actor(feats.history, feats.task, offsets)
        out = {
            "pos": pos[..., 0, :],
            "grip": grip[..., 0, :],
            "pos_chunk": pos,
            "grip_chunk": grip,
            "history": feats.history,
            "task": feats.task,
            "visual": f,
        }
        if subgoal is not None:
            out["subgoal"] = subgoal
        return out

    def _actor(
        self, history: torch.Tensor, task: torch.Tensor, offsets: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """[f_h, f_zeta (, offsets to the located points)] -> (pos (..., C, 3), gripper
        (..., C, 1) for the C = `action_chunk` steps from this one, subgoal offset or None).
        With a subgoal head, the actor also reads the predicted offset: moving toward a target
        it was told is an easy map. The pointer head's offset also reaches every step of the
        position chunk through a learned per-axis gain, one weight from the action."""
        parts = [history, task] if offsets is None else [history, task, offsets]
        actor_input = torch.cat(parts, dim=-1)
        if self.subgoal_head is None:
            return (*self.actor(actor_input), None)
        if self.subgoal_gain is None:  # the linear head
            subgoal = self.subgoal_head(actor_input)
        else:
            subgoal = self.subgoal_head(actor_input, offsets)
        pos, grip = self.actor(torch.cat([actor_input, subgoal], dim=-1))
        if self.subgoal_gain is not None:
            pos = pos + (self.subgoal_gain * subgoal)[..., None, :]
        return pos, grip, subgoal

    def loss(self, batch: dict) -> tuple[torch.Tensor, dict[str, float]]:
        """Behaviour cloning on one `EnvironmentIterations` item (its rollouts and demos).

        `pos_mse` is on standardised targets, so it is relative to the actions' variance:
        1.0 = predicting the mean; with `action_chunk` > 1 it is the whole chunk's, and
        `own_pos_mse` each frame's own action's. Frames without an action (each sequence's
        last, padding) are left out.
        """
        rollouts = batch["rollouts"]
        out = self(rollouts, batch["demos"])
        actions = rollouts["actions"].to(out["pos"].device)
        _, mask = check_sequences(rollouts, "rollouts")
        lengths = mask.sum(1)
        acted = torch.arange(mask.shape[1], device=mask.device)[None] < (lengths - 1)[:, None]
        if not acted.any():
            raise ValueError("loss: no frame with an action (every rollout has a single frame)")
        pos_loss, grip_loss, grip_acc = self._chunk_loss(out, rollouts, acted)
        total = pos_loss + grip_loss
        parts = {"pos_mse": pos_loss.item(), "grip_loss": grip_loss.item(), "grip_acc": grip_acc}
        if out["pos_chunk"].shape[-2] > 1:  # pos_mse is then the chunk's
            parts["own_pos_mse"] = self._own_action_mse(out, actions, acted)
        if self.subgoal_head is not None:
            if "subgoal" not in rollouts or "proprio" not in rollouts:
                raise ValueError(
                    "loss: config.subgoal_weight > 0 needs rollouts['subgoal'] and ['proprio'] "
                    "(stored TCP poses)"
                )
            offset = (rollouts["subgoal"] - rollouts["proprio"][..., :3]).to(
                out["pos"].device
            ) / SUBGOAL_SCALE_M
            subgoal_loss = F.mse_loss(out["subgoal"][acted], offset[acted])
            total = total + self.config.subgoal_weight * subgoal_loss
            parts["subgoal_mse"] = subgoal_loss.item()
        if self.inverse_dynamics is not None:
            f = out["visual"]
            pair = torch.cat([f[:, :-1], f[:, 1:]], dim=-1)[acted[:, :-1] & mask[:, 1:]]
            pred = self.inverse_dynamics(pair)
            id_pos, id_grip, _ = self._action_loss(
                pred[:, :3], pred[:, 3:], actions[:, :-1][acted[:, :-1] & mask[:, 1:]]
            )
            id_loss = id_pos + id_grip
            total = total + self.config.inverse_dynamics_weight * id_loss
            parts["inverse_dynamics"] = id_loss.item()
        parts["loss"] = total.item()
        return total, parts

    def _chunk_loss(
        self, out: dict, rollouts: dict, acted: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, float]:
        """The action loss of every acting frame's chunk: its k-th action against the episode's
        action k steps later, where the episode has one (`rollouts['action_chunks']`, read by
        `EnvironmentIterations(action_chunk=...)`); a chunk of 1 is the frame's own action."""
        chunk = out["pos_chunk"].shape[-2]
        if chunk == 1:
            targets, valid = rollouts["actions"][..., None, :], acted[..., None]
        elif "action_chunks" in rollouts and rollouts["action_chunks"].shape[-2] == chunk:
            targets = rollouts["action_chunks"]
            valid = rollouts["chunk_valid"].to(acted.device) & acted[..., None]
        else:
            raise ValueError(
                f"loss: config.action_chunk={chunk} needs rollouts['action_chunks'] (B, T, "
                f"{chunk}, 4) and ['chunk_valid'] (EnvironmentIterations(action_chunk={chunk}))"
            )
        targets = targets.to(out["pos"].device)
        return self._action_loss(out["pos_chunk"][valid], out["grip_chunk"][valid], targets[valid])

    def _own_action_mse(self, out: dict, actions: torch.Tensor, acted: torch.Tensor) -> float:
        """The position MSE of each frame's own action alone (a chunk's first), relative to the
        actions' variance: the number to compare across chunk sizes."""
        target = (actions.to(out["pos"].device) - self.action_mean) / self.action_std
        return F.mse_loss(out["pos"][acted], target[acted][:, :3]).item()

    def _action_loss(
        self, pos: torch.Tensor, grip: torch.Tensor, actions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, float]:
        target = (actions - self.action_mean) / self.action_std
        pos_loss = F.mse_loss(pos, target[:, :3])
        opened = (actions[:, 3:] > 0).float()
        if self.config.grip_loss == "bce":
            grip_loss = F.binary_cross_entropy_with_logits(grip, opened)
        else:
            grip_loss = F.mse_loss(grip, target[:, 3:])
        grip_acc = ((self._grip_open(grip) > 0).float() == opened).float().mean().item()
        return pos_loss, grip_loss, grip_acc

    def _grip_open(self, grip: torch.Tensor) -> torch.Tensor:
        """Gripper output -> >0 where open: a logit (bce), or the de-standardised value (mse)."""
        if self.config.grip_loss == "bce":
            return grip
        return grip * self.action_std[3] + self.action_mean[3]

    def to_action(self, pos: torch.Tensor, grip: torch.Tensor) -> torch.Tensor:
        """Standardised pos (..., 3) and gripper output (..., 1) -> env actions (..., 4)
        in [-1, 1]."""
        pos = (pos * self.action_std[:3] + self.action_mean[:3]).clamp(-1.0, 1.0)
        gripper = torch.where(self._grip_open(grip) > 0, 1.0, -1.0)
        return torch.cat([pos, gripper], dim=-1)

    # -- online ----------------------------------------------------------------------------
    def reset(self, demos: dict) -> None:
        """Encode the demonstrations once for a new rollout; switches to eval mode."""
        self.eval()
        device = self.action_mean.device
        with torch.inference_mode():
            memory = self.encode_demos(
                *(None if x is None else x.to(device) for x in self.demo_inputs(demos))
            )
            self._online = {
                "memory": memory,
                "state": self.init_state(memory),
                "t": 0,
                "history": None,
                "task": None,
                "queries": None,
                "located": None,
                "chunks": [],
            }
            if self.localizer is not None:
                self._online["queries"] = self.demo_queries(
                    {k: v.to(device) for k, v in demos.items() if isinstance(v, torch.Tensor)}
                )

    def act(self, obs: Any, proprio: Any = None) -> np.ndarray:
        """One step: a ManiSkill rgbd observation dict, or a (4, H, W) frame (plus its (5,)
        `proprio` for a policy that reads it) -> action (4,) float32."""
        if self._online is None:
            raise RuntimeError("act(): call reset(demos) first")
        device = self.action_mean.device
        frame = self.observation_frame(obs).to(device)
        if self.config.proprio:
            proprio = torch.as_tensor(
                self.observation_proprio(obs) if proprio is None else proprio, dtype=torch.float32
            )
            if proprio.shape != (PROPRIO_DIM,):
                raise ValueError(
                    f"proprio of shape {tuple(proprio.shape)}: expected ({PROPRIO_DIM},)"
                )
            proprio = proprio[None].to(device)
        with torch.inference_mode():
            f_t = self.embed(frame[None], proprio=proprio)
            history, task, self._online["state"] = self.step(
                f_t, self._online["memory"], self._online["state"]
            )
            offsets = None
            if self.localizer is not None:
                if self._online["located"] is None:  # the rollout's first frame
                    self._online["located"] = self.localizer.locate(
                        frame[None], self._online["queries"]
                    ).flatten(1)
                offsets = self.located_offsets(self._online["located"], proprio)
            pos, grip, _ = self._actor(history, task, offsets)
            pos, grip = self._ensemble(pos[0], grip[0])
            action = self.to_action(pos, grip)
        self._online.update(history=history[0], task=task[0], t=self._online["t"] + 1)
        return action.cpu().numpy().astype(np.float32)

    def _ensemble(self, pos: torch.Tensor, grip: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """This step's chunk (C, 3), (C, 1) -> the action for now, from it and the chunks of
        the last C - 1 steps (`ensemble_latest`)."""
        chunks = self._online["chunks"]
        chunks.append((pos, grip))
        del chunks[: -len(pos)]
        return ensemble_latest(
            torch.stack([c[0] for c in chunks]), torch.stack([c[1] for c in chunks])
        )

    @staticmethod
    def ensemble_chunks(pos: torch.Tensor, grip: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Batched `act`: chunks pos (B, T, C, 3), grip (B, T, C, 1) -> the action each step
        takes online, (B, T, 3) and (B, T, 1)."""
        chunk = pos.shape[2]
        steps = [
            ensemble_latest(
                pos[:, max(0, t - chunk + 1) : t + 1], grip[:, max(0, t - chunk + 1) : t + 1]
            )
            for t in range(pos.shape[1])
        ]
        return torch.stack([p for p, _ in steps], 1), torch.stack([g for _, g in steps], 1)

    def observation_frame(self, obs: Any) -> torch.Tensor:
        if isinstance(obs, torch.Tensor) and obs.dim() == 3:
            if obs.shape[0] != 4:
                raise ValueError(f"frame of shape {tuple(obs.shape)}: expected (4, H, W)")
            return obs.float()
        try:
            camera = obs["sensor_data"][self.camera]
            rgb, depth = camera["rgb"], camera["depth"]
        except (KeyError, TypeError) as e:
            raise ValueError(
                "observation: expected a (4, H, W) frame or an rgbd dict with "
                f"sensor_data/{self.camera}/rgb, depth"
            ) from e
        rgb, depth = (
            x.cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x) for x in (rgb, depth)
        )
        if rgb.ndim == 3:
            rgb, depth = rgb[None], depth[None]
        return to_frames(rgb[:1], depth[:1])[0]

    @staticmethod
    def observation_proprio(obs: Any) -> np.ndarray:
        """(5,) TCP position and finger joints of a ManiSkill observation dict (first env)."""
        try:
            tcp_pose, qpos = obs["extra"]["tcp_pose"], obs["agent"]["qpos"]
        except (KeyError, TypeError, IndexError) as e:
            raise ValueError(
                "observation: this policy reads proprioception; expected an observation dict "
                "with extra/tcp_pose and agent/qpos (or pass act(frame, proprio=...))"
            ) from e
        proprio = proprio_from_obs(tcp_pose, qpos)
        return proprio.reshape(-1, proprio.shape[-1])[0]

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

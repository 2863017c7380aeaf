"""How well can the expert's actions be predicted from privileged low-dimensional inputs?

An MLP maps the TCP position, the finger joints and the time step, with or without the offset
to where the current stage ends (`aed_models.data.stage_subgoals`), to the expert's position
action, and reports the held-out MSE as a share of the actions' variance (the policies'
`pos_mse`). It bounds what a policy that localises its target perfectly could reach, and shows
how much the stage target is worth (why the `mini` policies predict it; see
`PolicyConfig.subgoal_weight`).

    python scripts/action_floor.py --data runs/exp/PressButton/data/base

Press Button (27 environments, seed 0): 0.10 with the stage target, 0.26 without.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch
import tyro

from aed_models.data import load_episodes, proprio_from_obs, stage_subgoals

logger = logging.getLogger("action_floor")


@dataclass
class Config:
    data: Path = Path("runs/PressButton/data/base")
    """Base collection: its demonstrations and agent successes are read."""
    steps: int = 3000
    seed: int = 0


def privileged_inputs(data: Path) -> tuple[torch.Tensor, torch.Tensor]:
    """Per action: [TCP xyz, fingers, t / 100, stage-target offset / 10 cm] (N, 9), position action
    (N, 3)."""
    inputs, actions = [], []
    for ref in (e for e in load_episodes(data) if e.success):
        with h5py.File(ref.path, "r") as h5:
            group = h5[ref.traj]
            proprio = proprio_from_obs(group["obs/extra/tcp_pose"][()], group["obs/agent/qpos"][()])
            action, stage = group["actions"][()], group["stage"][()]
        n, tcp = len(action), proprio[:, :3]
        offset = (stage_subgoals(tcp, stage) - tcp)[:n] / 0.1
        inputs.append(np.concatenate([proprio[:n], np.arange(n)[:, None] / 100.0, offset], axis=1))
        actions.append(action[:, :3])
    return torch.tensor(np.concatenate(inputs), dtype=torch.float32), torch.tensor(
        np.concatenate(actions), dtype=torch.float32
    )


def held_out_mse(x: torch.Tensor, y: torch.Tensor, steps: int, seed: int) -> float:
    torch.manual_seed(seed)
    model = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 256),
        torch.nn.ReLU(),
        torch.nn.Linear(256, 3),
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    order = torch.randperm(len(x))
    train, test = order[: int(0.8 * len(x))], order[int(0.8 * len(x)) :]
    for _ in range(steps):
        i = train[torch.randint(0, len(train), (256,))]
        loss = ((model(x[i]) - y[i]) ** 2).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        return float(((model(x[test]) - y[test]) ** 2).mean())


def main(cfg: Config) -> None:
    x, y = privileged_inputs(cfg.data)
    y = (y - y.mean(0)) / y.std(0).clamp_min(1e-3)  # as the policies standardise actions
    logger.info("%d actions of %s", len(x), cfg.data)
    logger.info(
        "with the stage target: %.3f of the variance", held_out_mse(x, y, cfg.steps, cfg.seed)
    )
    logger.info("without it: %.3f", held_out_mse(x[:, :6], y, cfg.steps, cfg.seed))


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(tyro.cli(Config))

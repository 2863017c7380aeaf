"""Where a localizer policy's rollouts went wrong: the target located in each rollout's first
frame against the object's true position, the TCP's closest approach to it, and the outcome.

Splits the rollouts into those whose located target lies within `--near` of the object and the
rest, with the success count of each: a policy that fails where it was told the right place
fails at control, one that fails only where the localizer missed fails at localization. For a
failure at control, where its stage-target head aimed when the TCP came closest tells whether
it aimed wrong (the head) or did not get where it aimed (the actor). Where the gripper first
closed (the first action with a negative gripper command) against the object tells a grasp
that missed from one that was never tried; where the policy's own output, run on the recorded
frames, first says close tells the same of the policy's decision on any episodes (on expert
episodes given as `--rollouts`: whether it would close where the expert does). The follow
gain tells whether the actor goes where it was told: the first stage's located point moved
by `--shift` along x (then y), how far the first `--steps` position actions it takes online (on
the rollout's own frames) move, as a share of the shift (the actions' metres per unit fitted on
the rollouts' own motion); 1 = it follows fully.

    python scripts/rollout_localization.py --policy runs/PressButton/policies/scan/policy.pt \
        --rollouts runs/PressButton/rollouts/scan/novel --demos runs/PressButton/data/novel

On the agent's expert successes instead of rollouts, add `--roles agent_success` (e.g.
`--rollouts runs/PressButton/data/novel-labelled`).
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch
import tyro

from aed_eval.scoring import Demonstrations
from aed_models.data import EpisodeReader, FrameSequence, pad_sequences
from aed_models.policies import load_policy
from aed_models.policies.base import SUBGOAL_SCALE_M
from aed_tasks import trajectory

ERROR_BINS_CM = (0, 1, 2, 3, 5, 10, float("inf"))  # the located error's bins of the success split


@dataclass
class Config:
    policy: Path
    """A policy checkpoint with a target localizer."""
    rollouts: Path
    """Its rollouts (`aed rollout`)."""
    demos: Path
    """The collection holding the rollouts' demonstrations."""
    roles: tuple[str, ...] = ()
    """Read only these roles of `rollouts` (e.g. agent_success of an expert collection; none:
    all)."""
    per_env: int = 0
    """Read at most this many episodes of each environment, in collection order (0: all)."""
    target: str = "button"
    """The task object (an actor or articulation of the env states) the first stage acts on."""
    num_demos: int = 5
    near: float = 0.03
    """Metres: a located target this close (horizontally) to the object counts as found."""
    shift: float = 0.05
    """Metres the first stage's located point is moved by to measure the follow gain."""
    steps: int = 30
    """The first frames whose position actions the follow gain sums."""


@torch.no_grad()
def main(cfg: Config) -> dict:
    policy = load_policy(cfg.policy)
    if policy.localizer is None:
        raise ValueError(f"{cfg.policy}: a policy without a target localizer")
    refs = [
        ref
        for ref in trajectory.scan_collection(cfg.rollouts).episodes()
        if not cfg.roles or ref.role in cfg.roles
    ]
    if cfg.per_env:
        refs = first_per_env(refs, cfg.per_env)
    if not refs:
        roles = f" of roles {list(cfg.roles)}" if cfg.roles else ""
        raise ValueError(f"{cfg.rollouts}: no episodes{roles}")
    demos = Demonstrations(cfg.demos, refs[0].split, cfg.num_demos)
    reader = EpisodeReader()
    located, approach, success, envs, aimed, closed_at = [], [], [], [], [], []
    close_offsets, responses, commanded, moved = [], [], [], []
    recorded_closes, own_closes = [], []
    for ref in sorted(refs, key=lambda r: r.env_index):
        sequence = reader.read(ref)
        points = policy.localizer.locate(
            sequence.frames[:1], policy.demo_queries(demos[ref.env_index])
        )
        point = points[0, 0].numpy()
        run = PolicyRun(policy, sequence, demos[ref.env_index])
        outputs = run(points)
        predicted = stage_targets(run, outputs)
        responses.append(action_response(run, outputs, points, cfg.shift, cfg.steps))
        target, tcp_xyz, actions = read_track(ref, cfg.target)
        xy, tcp = target[:2], tcp_xyz[:, :2]
        close = first_close(target, tcp_xyz, actions)
        own = run.policy.to_action(*run.online_actions(outputs))[0, :-1].numpy()
        recorded_closes.append(close)
        own_closes.append(first_close(target, tcp_xyz, own))
        steps = min(cfg.steps, len(actions))
        commanded.append(actions[:steps, :2].sum(0))
        moved.append(tcp[steps] - tcp[0])
        located.append(float(np.linalg.norm(point[:2] - xy)))
        distance = np.linalg.norm(tcp - xy, axis=1)
        approach.append(float(distance.min()))
        closest = int(distance.argmin())
        aimed.append(
            float("nan") if predicted is None else float(np.linalg.norm(predicted[closest] - xy))
        )
        closed_at.append(float(np.linalg.norm(close[1][:2])) if close else float("nan"))
        close_offsets.append(close[1][:2] if close else np.full(2, np.nan))
        success.append(bool(ref.success))
        envs.append(ref.env_index)
    located, approach, success, aimed, closed_at = map(
        np.asarray, (located, approach, success, aimed, closed_at)
    )
    near = located < cfg.near
    closed = closed_at[np.isfinite(closed_at)]
    close_offsets = np.abs(np.stack(close_offsets))[np.isfinite(closed_at)]
    # metres of TCP motion per unit of summed action, per axis, least squares through 0
    commanded, moved = np.stack(commanded), np.stack(moved)
    with np.errstate(invalid="ignore", divide="ignore"):  # no commanded motion: no gain (NaN)
        metres_per_unit = (commanded * moved).sum(0) / (commanded**2).sum(0)
    gain = np.median(np.stack(responses), axis=0) * metres_per_unit / cfg.shift
    result = {
        "rollouts": len(refs),
        "located_median_cm": 100 * float(np.median(located)),
        "closest_approach_median_cm": 100 * float(np.median(approach)),
        "first_close": {
            "rollouts": len(closed),
            "median_cm": 100 * float(np.median(closed)) if len(closed) else None,
            "within_2cm": int((closed < 0.02).sum()),
            "median_abs_cm": {
                axis: 100 * float(np.median(close_offsets[:, i])) if len(closed) else None
                for i, axis in enumerate("xy")
            },
            **close_timing(recorded_closes),
        },
        "own_first_close": own_first_close(recorded_closes, own_closes),
        "expert_first_close": expert_first_close(
            [r for env in demos.envs() for r in demos.refs[env]], cfg.target
        ),
        "follow_gain": {
            "shift_cm": 100 * cfg.shift,
            "steps": cfg.steps,
            "actions": "online",
            **{
                axis: round(float(gain[i]), 3) if np.isfinite(gain[i]) else None
                for i, axis in enumerate("xy")
            },
        },
        "found": {"rollouts": int(near.sum()), "successes": int(success[near].sum())},
        "missed": {"rollouts": int((~near).sum()), "successes": int(success[~near].sum())},
        "failures_found_closest_approach_cm": sorted(
            round(100 * a, 1) for a in approach[near & ~success]
        ),
        "failures_found_aimed_at_closest_cm": sorted(
            round(100 * a, 1) for a in aimed[near & ~success]
        ),
        "by_located_error_cm": {
            f"{low:g}-{high:g}": {
                "rollouts": int(inside.sum()),
                "successes": int(success[inside].sum()),
            }
            for low, high in zip(ERROR_BINS_CM[:-1], ERROR_BINS_CM[1:], strict=True)
            for inside in [(100 * located >= low) & (100 * located < high)]
        },
        "per_rollout": [
            {
                "env_index": e,
                "located_cm": round(100 * x, 2),
                "closest_cm": round(100 * a, 2),
                "aimed_at_closest_cm": round(100 * t, 2),
                "first_close_cm": round(100 * c, 2) if np.isfinite(c) else None,
                "success": bool(ok),
            }
            for e, x, a, t, c, ok in zip(
                envs, located, approach, aimed, closed_at, success, strict=True
            )
        ],
    }
    print(json.dumps(result, indent=1))
    return result


def first_per_env(refs: list, n: int) -> list:
    """The first `n` episodes of each environment, in the given order."""
    taken: Counter = Counter()
    kept = []
    for ref in refs:
        if taken[ref.env_index] < n:
            taken[ref.env_index] += 1
            kept.append(ref)
    return kept


def read_track(ref, target: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An episode's object position in its first frame (3,), TCP positions (T + 1, 3) and
    actions (T, 4)."""
    with h5py.File(ref.path, "r") as h5:
        group = h5[ref.traj]
        states = group["env_states"]
        kind = "articulations" if target in states["articulations"] else "actors"
        return (
            states[kind][target][0, :3],
            group["obs/extra/tcp_pose"][()][:, :3],
            group["actions"][()],
        )


def first_close(
    point: np.ndarray, tcp: np.ndarray, actions: np.ndarray
) -> tuple[int, np.ndarray] | None:
    """The first step that commands the gripper closed and the TCP's offset from the object
    (3,) on it; None for an episode that never closes."""
    closes = np.flatnonzero(actions[:, -1] < 0)
    if not len(closes):
        return None
    return int(closes[0]), tcp[closes[0]] - point


def close_timing(closes: list[tuple[int, np.ndarray] | None]) -> dict:
    """The median height of the TCP above the object's centre (cm) and the median step at
    episodes' first closes (`first_close`; None: never closed, skipped)."""
    closed = [c for c in closes if c is not None]
    return {
        "median_height_cm": 100 * float(np.median([o[2] for _, o in closed])) if closed else None,
        "median_step": float(np.median([s for s, _ in closed])) if closed else None,
    }


def close_summary(closes: list[tuple[int, np.ndarray] | None]) -> dict:
    """Of episodes' first closes (`first_close`, None: never closed): how many closed, the
    TCP's median horizontal distance to the object there, and `close_timing`."""
    closed = [c for c in closes if c is not None]
    distances = [float(np.linalg.norm(offset[:2])) for _, offset in closed]
    return {
        "episodes": len(closes),
        "closed": len(closed),
        "median_cm": 100 * float(np.median(distances)) if distances else None,
        **close_timing(closed),
    }


def expert_first_close(refs: list, target: str) -> dict:
    """Where and when the demonstrations (the expert) first close the gripper."""
    return close_summary([first_close(*read_track(ref, target)) for ref in refs])


def own_first_close(recorded: list, own: list) -> dict:
    """Where and when the policy's own action (its chunks' temporal ensemble, as online), run
    on each episode's recorded frames, first says close (`close_summary`), and by how many
    steps before the recorded first close (median over the episodes where both close). On
    expert episodes given as `--rollouts` this is where the policy would have closed on the
    expert's way down."""
    leads = [r[0] - o[0] for r, o in zip(recorded, own, strict=True) if r and o]
    return {
        **close_summary(own),
        "median_steps_before_recorded": float(np.median(leads)) if leads else None,
    }


class PolicyRun:
    """The policy run on one rollout's own frames (as online), given where the stage targets
    are located (1, K, 3): the outputs of `policy.forward`, the rollout padded once."""

    def __init__(self, policy: torch.nn.Module, sequence: FrameSequence, demos: dict):
        self.policy, self.demos = policy, demos
        self.rollout = pad_sequences([sequence])

    @torch.no_grad()
    def __call__(self, points: torch.Tensor) -> dict[str, torch.Tensor]:
        located = points.flatten(1)[:, None].expand(-1, self.rollout["mask"].shape[1], -1)
        return self.policy({**self.rollout, "located": located}, self.demos)

    def online_actions(self, outputs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """What `act` would take at each step, (1, T, 3) and (1, T, 1): the temporal ensemble
        of the last `action_chunk` chunks, as online."""
        return self.policy.ensemble_chunks(outputs["pos_chunk"], outputs["grip_chunk"])


def action_response(
    run: PolicyRun, outputs: dict, points: torch.Tensor, shift: float, steps: int
) -> np.ndarray:
    """(2,) how much the sum of the first `steps` position actions the policy takes online
    (x, y; the env's action units) changes, against `outputs` (the run at `points`), when the
    first stage's located point moves by `shift` metres along that axis."""

    def summed(out: dict) -> torch.Tensor:
        pos, _ = run.online_actions(out)
        return (pos[0, :steps] * run.policy.action_std[:3]).sum(0)

    base = summed(outputs)
    response = np.zeros(2)
    for axis in range(2):
        moved = points.clone()
        moved[0, 0, axis] += shift
        response[axis] = float((summed(run(moved)) - base)[axis])
    return response


def stage_targets(run: PolicyRun, outputs: dict) -> np.ndarray | None:
    """(T, 2) where the policy's stage-target head puts the current stage's end at each frame
    (TCP + predicted offset; horizontal) in `outputs`; None for a policy without that head."""
    if "subgoal" not in outputs:
        return None
    tcp = run.rollout["proprio"][0, :, :3]
    return (tcp + SUBGOAL_SCALE_M * outputs["subgoal"][0])[:, :2].numpy()


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    main(tyro.cli(Config))

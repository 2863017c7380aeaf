"""Scripted, motion-planned experts and error injection.

Every segment of an expert is planned with ManiSkill's mplib motion planner (a screw motion,
checked for joint limits and self-collision) and then tracked in the agent's own action
space, `pd_ee_delta_pos`, so that the recorded actions are exactly what a policy must output.
Where the screw is blocked, the expert follows the straight segment and lets the controller's
IK find the way; it never falls back to RRT, whose unseeded sampling (OMPL, pinocchio) would
make episodes differ between runs of the same seed.
With an `ErrorSpec`, the task's script deviates at the critical moment (grasp, release,
push...) and calls `mark_error()`: labels are 0 before that step and 1 from it on.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from aed_tasks.episode import Episode

logger = logging.getLogger(__name__)

OPEN, CLOSED = 1.0, -1.0
MAX_DELTA = 0.1  # metres per unit action of pd_ee_delta_pos (ManiSkill's Panda config)


@dataclass(frozen=True)
class ErrorSpec:
    """A behaviour error to inject: `kind` is one of the task's `error_kinds`."""

    kind: str


class EpisodeOver(Exception):
    """The env terminated (success or irrecoverable failure): the script stops early."""


def _to_numpy(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


class ScriptedExpert:
    """Drives one episode: plans with mplib, tracks in end-effector deltas, records.

    Args:
        env: an AED env (possibly wrapped, e.g. by `RecordEpisode`), already reset.
        rng: the episode's generator for path and speed variation.
        speed: cruise speed in metres per control step (the episode's speed profile).
    """

    def __init__(self, env: Any, rng: np.random.Generator, speed: float):
        from mani_skill.examples.motionplanning.panda.motionplanner import (
            PandaArmMotionPlanningSolver,
        )

        self.env = env
        self.base = env.unwrapped
        self.rng = rng
        self.speed = speed
        solver = PandaArmMotionPlanningSolver(
            env, debug=False, vis=False, base_pose=self.base.agent.robot.pose,
            visualize_target_grasp_pose=False, print_env_info=False,
        )  # fmt: skip
        self.planner = solver.planner
        self.orientation = self.base.agent.tcp.pose.sp.q  # held fixed: the actions are positions only
        self.gripper = OPEN
        self.onset: int | None = None
        self.actions: list[np.ndarray] = []
        self.success: list[bool] = []
        self.fail: list[bool] = []
        self.stage: list[int] = []
        self.observations: list[Any] = []
        self.terminated = False

    # --- state ------------------------------------------------------------------------------
    @property
    def tcp(self) -> np.ndarray:
        return _to_numpy(self.base.agent.tcp.pose.p[0]).astype(np.float64)

    @property
    def steps(self) -> int:
        return len(self.actions)

    def mark_error(self) -> None:
        """The intervention starts now: this and every later step is labelled 1."""
        if self.onset is None:
            self.onset = self.steps

    # --- primitives -------------------------------------------------------------------------
    def step(self, delta: np.ndarray, gripper: float | None = None) -> None:
        if self.terminated:
            raise EpisodeOver
        if gripper is not None:
            self.gripper = gripper
        action = np.concatenate([np.clip(delta / MAX_DELTA, -1, 1), [self.gripper]]).astype(np.float32)
        obs, _, terminated, truncated, info = self.env.step(action)
        self.actions.append(action)
        self.success.append(bool(_to_numpy(info["success"]).reshape(-1)[0]))
        self.fail.append(bool(_to_numpy(info["fail"]).reshape(-1)[0]))
        self.stage.append(int(_to_numpy(info["stage"]).reshape(-1)[0]))
        self.observations.append(obs)
        self.terminated = bool(_to_numpy(terminated).reshape(-1)[0] or _to_numpy(truncated).reshape(-1)[0])

    def plan(self, target: np.ndarray) -> np.ndarray:
        """TCP positions (N, 3) along an mplib screw plan from here to `target` (top-down gripper).

        A blocked screw (a joint limit or self-collision on the way) gives the straight segment.
        """
        goal = np.concatenate([target, self.orientation])
        qpos = _to_numpy(self.base.agent.robot.get_qpos()[0])
        result = self.planner.plan_screw(goal, qpos, time_step=self.base.control_timestep)
        if result["status"] != "Success":
            logger.debug("screw to %s blocked (%s): straight segment", np.round(target, 3), result["status"])
            return np.asarray([self.tcp, target])
        model, link = self.planner.pinocchio_model, self.planner.move_group_link_id
        origin = _to_numpy(self.base.agent.robot.pose.p[0])
        path = []
        for q in result["position"]:
            full = qpos.copy()
            full[: len(q)] = q
            model.compute_forward_kinematics(full)
            path.append(model.get_link_pose(link)[:3] + origin)
        return np.asarray([self.tcp, *path, target])

    def move_to(self, target: np.ndarray, speed: float | None = None, tol: float = 0.006, settle: int = 12) -> None:
        """Follow a planned path to `target` at `speed` (m/step), then settle within `tol`."""
        target = np.asarray(target, dtype=np.float64)
        waypoints = resample(self.plan(target), speed or self.speed)
        for waypoint in waypoints:
            self.step(waypoint - self.tcp)
        for _ in range(settle):
            error = target - self.tcp
            if np.linalg.norm(error) < tol:
                break
            self.step(error)

    def move_by(self, offset: np.ndarray, speed: float | None = None, **kwargs: Any) -> None:
        self.move_to(self.tcp + np.asarray(offset, dtype=np.float64), speed, **kwargs)

    def close_gripper(self, steps: int = 8) -> None:
        for _ in range(steps):
            self.step(np.zeros(3), CLOSED)

    def open_gripper(self, steps: int = 6) -> None:
        for _ in range(steps):
            self.step(np.zeros(3), OPEN)

    def wait(self, steps: int) -> None:
        for _ in range(steps):
            self.step(np.zeros(3))

    def jitter(self, scale: float) -> np.ndarray:
        """A random xy offset: paths differ between episodes (length-variant demonstrations)."""
        return np.array([*self.rng.uniform(-scale, scale, 2), 0.0])


def resample(path: np.ndarray, spacing: float) -> np.ndarray:
    """Points every `spacing` metres along a polyline (its end always included)."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    length = float(seg.sum())
    if length < 1e-6:
        return path[-1:]
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(np.ceil(length / spacing)), 1)
    s = np.linspace(0, length, n + 1)[1:]
    return np.stack([np.interp(s, cum, path[:, i]) for i in range(3)], axis=1)


def expert_speed(rng: np.random.Generator, demonstrator: bool) -> float:
    """Cruise speed (m per 50 ms step): the demonstrator moves faster than the agent's expert."""
    return float(rng.uniform(0.016, 0.024) if demonstrator else rng.uniform(0.010, 0.016))


def solve(
    env: Any, seed: int, error: ErrorSpec | None = None, env_index: int | None = None, suboptimal: bool = False
) -> Episode:
    """Run the task's expert for one episode (optionally with an injected error).

    `env` is an AED env made with `gym.make` (any wrappers, e.g. `RecordEpisode`, see the
    same steps). The episode is reset with `seed` (and `env_index`, if given). With
    `suboptimal=True` the expert first fails in one of the task's recoverable ways, then
    starts over from where it is and succeeds (the demonstration-quality experiment).
    """
    base = env.unwrapped
    if error is not None and error.kind not in base.error_kinds:
        raise ValueError(f"unknown error kind {error.kind!r} for {base.task_name}; known: {list(base.error_kinds)}")
    if suboptimal and (error is not None or not base.recoverable_errors):
        raise ValueError(f"suboptimal episodes of {base.task_name} need error=None and recoverable_errors")
    options = {} if env_index is None else {"env_index": env_index}
    obs, _ = env.reset(seed=seed, options=options)
    stream = 0 if error is None else 1 + base.error_kinds.index(error.kind)
    rng = np.random.default_rng([seed, stream, int(suboptimal)])
    expert = ScriptedExpert(env, rng, expert_speed(rng, base.demonstrator))
    try:
        if suboptimal:
            first_try = ErrorSpec(str(rng.choice(base.recoverable_errors)))
            base.expert_script(expert, first_try)
            expert.onset = None  # a demonstration: the failed attempt is part of it, not an error
            base.expert_script(expert, None)
        else:
            base.expert_script(expert, error)
    except EpisodeOver:
        pass
    if error is not None and expert.onset is None:
        raise RuntimeError(f"{base.task_name} script never marked the onset of error {error.kind!r}")
    episode = _episode(base, seed, error, expert, obs)
    episode.suboptimal = suboptimal
    return episode


def _episode(base: Any, seed: int, error: ErrorSpec | None, expert: ScriptedExpert, first_obs: Any) -> Episode:
    steps = expert.steps
    labels = np.zeros(steps, dtype=np.uint8)
    if expert.onset is not None:
        labels[expert.onset :] = 1
    rgb: dict[str, np.ndarray] = {}
    depth: dict[str, np.ndarray] = {}
    if isinstance(first_obs, dict) and "sensor_data" in first_obs:
        frames = [first_obs, *expert.observations]
        for camera, data in first_obs["sensor_data"].items():
            if "rgb" in data:
                rgb[camera] = np.stack([_to_numpy(o["sensor_data"][camera]["rgb"][0]) for o in frames])
            if "depth" in data:
                depth[camera] = np.stack([_to_numpy(o["sensor_data"][camera]["depth"][0]) for o in frames])
    return Episode(
        env_id=base.spec.id if base.spec is not None else f"AED-{base.task_name}-{base.split}",
        task=base.task_name, split=base.split, env_index=base.env_index, seed=seed,
        demonstrator=base.demonstrator, control_mode=base.control_mode,
        actions=np.asarray(expert.actions, dtype=np.float32).reshape(-1, 4),
        success=np.asarray(expert.success, dtype=bool), fail=np.asarray(expert.fail, dtype=bool),
        stage=np.asarray(expert.stage, dtype=np.int16), error_label=labels,
        error_kind=None if error is None else error.kind, error_onset=expert.onset,
        rgb=rgb, depth=depth, expert_speed=expert.speed,
    )  # fmt: skip

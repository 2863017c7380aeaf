"""Scripted, motion-planned experts and error injection.

Every segment of an expert is planned with ManiSkill's mplib motion planner (a screw motion,
checked for joint limits and self-collision) and then tracked in the agent's own action
space, `pd_ee_delta_pos`, so that the recorded actions are exactly what a policy must output.
Where the screw is blocked, the expert follows the straight segment and lets the controller's
IK find the way; it never falls back to RRT, whose unseeded sampling (OMPL, pinocchio) would
make episodes differ between runs of the same seed.
With an `ErrorSpec`, the task's script deviates at the critical moment (grasp, release,
push...) and calls `mark_error()`: labels are 0 before that step and 1 from it on.

The onset is the visible departure. The clean and the intervened episode of one seed (and
environment) share one random stream, `expert.rng`, so they are the same episode until the
intervened script departs from what the clean expert would do from the same state. A task's
`expert_script` keeps this true by two rules:
- before the onset, the intervened script draws from `expert.rng` exactly the values the
  clean script draws, in the same order; values only an error needs are drawn from
  `expert.error_rng` (a stream of their own, any time) or from `expert.rng` at or after
  the onset;
- `mark_error()` is called right before the first step whose action differs from the clean
  expert's action, never earlier (e.g. a press that stops short is marked where it stops, not
  where it starts). `move_to(..., stop_before=...)` follows the clean motion and stops where
  an error departs from it.
`tests/test_departure.py` checks both for every task and kind (`departure()` measures it).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
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
    """The time limit cut the episode (`truncated`): the script stops where it is.

    Termination (success, irrecoverable failure) does not stop a script: successes and
    failures alike run to the script's end, retreat and rest, so that no ending is a cue.
    """


def _to_numpy(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


class ScriptedExpert:
    """Drives one episode: plans with mplib, tracks in end-effector deltas, records.

    Args:
        env: an AED env (possibly wrapped, e.g. by `RecordEpisode`), already reset.
        rng: the episode's generator for path and speed variation, shared by the clean and
            every intervened episode of one seed (see the module docstring).
        error_rng: the generator of values only an injected error needs (its own stream).
        speed: cruise speed in metres per control step (the episode's speed profile).
        keep_observations: keep every step's observation (False when a recorder keeps them).
    """

    def __init__(
        self,
        env: Any,
        rng: np.random.Generator,
        speed: float,
        error_rng: np.random.Generator | None = None,
        keep_observations: bool = True,
    ):
        from mani_skill.examples.motionplanning.panda.motionplanner import (
            PandaArmMotionPlanningSolver,
        )

        self.env = env
        self.base = env.unwrapped
        self.rng = rng
        self.error_rng = np.random.default_rng(0) if error_rng is None else error_rng
        self.speed = speed
        self.keep_observations = keep_observations
        solver = PandaArmMotionPlanningSolver(
            env,
            debug=False,
            vis=False,
            base_pose=self.base.agent.robot.pose,
            visualize_target_grasp_pose=False,
            print_env_info=False,
        )
        self.planner = solver.planner
        self.orientation = (
            self.base.agent.tcp.pose.sp.q
        )  # held fixed: the actions are positions only
        self.gripper = OPEN
        self.onset: int | None = None
        self.actions: list[np.ndarray] = []
        self.success: list[bool] = []
        self.fail: list[bool] = []
        self.stage: list[int] = []
        self.observations: list[Any] = []
        self.truncated = False  # the env's time limit was reached

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
        """One control step; `terminated` is ignored (the script goes on), truncation ends it."""
        if self.truncated:
            raise EpisodeOver
        if gripper is not None:
            self.gripper = gripper
        action = np.concatenate([np.clip(delta / MAX_DELTA, -1, 1), [self.gripper]]).astype(
            np.float32
        )
        obs, _, _, truncated, info = self.env.step(action)
        self.actions.append(action)
        self.success.append(bool(_to_numpy(info["success"]).reshape(-1)[0]))
        self.fail.append(bool(_to_numpy(info["fail"]).reshape(-1)[0]))
        self.stage.append(int(_to_numpy(info["stage"]).reshape(-1)[0]))
        if self.keep_observations:
            self.observations.append(obs)
        self.truncated = bool(_to_numpy(truncated).reshape(-1)[0])

    def plan(self, target: np.ndarray) -> np.ndarray:
        """TCP positions (N, 3) along an mplib screw plan from here to `target` (top-down gripper).

        A blocked screw (a joint limit or self-collision on the way) gives the straight segment.
        """
        goal = np.concatenate([target, self.orientation])
        qpos = _to_numpy(self.base.agent.robot.get_qpos()[0])
        result = self.planner.plan_screw(goal, qpos, time_step=self.base.control_timestep)
        if result["status"] != "Success":
            logger.debug(
                "screw to %s blocked (%s): straight segment", np.round(target, 3), result["status"]
            )
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

    def move_to(
        self,
        target: np.ndarray,
        speed: float | None = None,
        tol: float = 0.006,
        settle: int = 12,
        stop_before: Callable[[np.ndarray], bool] | None = None,
    ) -> bool:
        """Follow a planned path to `target` at `speed` (m/step), then settle within `tol`.

        With `stop_before`, stop short before the first waypoint for which it is True and
        return True (an error's departure from the clean path); else return False.
        """
        target = np.asarray(target, dtype=np.float64)
        waypoints = resample(self.plan(target), speed or self.speed)
        for waypoint in waypoints:
            if stop_before is not None and stop_before(waypoint):
                return True
            self.step(waypoint - self.tcp)
        for _ in range(settle):
            error = target - self.tcp
            if np.linalg.norm(error) < tol:
                break
            if stop_before is not None and stop_before(target):
                return True
            self.step(error)
        return False

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
    env: Any,
    seed: int,
    error: ErrorSpec | None = None,
    env_index: int | None = None,
    suboptimal: bool = False,
    frames: bool = True,
) -> Episode:
    """Run the task's expert for one episode (optionally with an injected error).

    `env` is an AED env made with `gym.make` (any wrappers, e.g. `RecordEpisode`, see the
    same steps). The episode is reset with `seed` (and `env_index`, if given). With
    `suboptimal=True` the expert first fails in one of the task's recoverable ways, then
    starts over from where it is and succeeds (the demonstration-quality experiment). With
    `frames=False` the episode carries no RGB-D frames (a step recorder around `env` keeps them).
    """
    base = env.unwrapped
    if error is not None and error.kind not in base.error_kinds:
        raise ValueError(
            f"unknown error kind {error.kind!r} for {base.task_name}; "
            f"known: {list(base.error_kinds)}"
        )
    if suboptimal and (error is not None or not base.recoverable_errors):
        raise ValueError(
            f"suboptimal episodes of {base.task_name} need error=None and recoverable_errors"
        )
    options = {} if env_index is None else {"env_index": env_index}
    obs, _ = env.reset(seed=seed, options=options)
    # one stream for the clean and every intervened episode of a seed: identical up to the onset
    rng = np.random.default_rng([seed, 0, int(suboptimal)])
    error_rng = np.random.default_rng(
        [seed, 1 + (base.error_kinds.index(error.kind) if error else 0)]
    )
    expert = ScriptedExpert(
        env, rng, expert_speed(rng, base.demonstrator), error_rng, keep_observations=frames
    )
    first_attempt = None
    try:
        if suboptimal:
            first_try = ErrorSpec(str(rng.choice(base.recoverable_errors)))
            base.expert_script(expert, first_try)
            first_attempt = (
                expert.steps,
                first_try.kind,
                _first_attempt_problem(base, expert, first_try.kind),
            )
            expert.onset = None  # a demonstration: the failed attempt is part of it, not an error
            base.expert_script(expert, None)
        else:
            base.expert_script(expert, error)
    except EpisodeOver:  # the time limit cut the script: the caller decides (collection rejects it)
        logger.debug(
            "%s seed %d: the time limit cut the script at step %d",
            base.task_name,
            seed,
            expert.steps,
        )
    if error is not None and expert.onset is None:
        raise RuntimeError(
            f"{base.task_name} script never marked the onset of error {error.kind!r}"
        )
    episode = _episode(base, seed, error, expert, obs)
    episode.suboptimal = suboptimal
    if suboptimal and first_attempt is not None:
        episode.first_attempt_steps, episode.first_attempt_kind, episode.first_attempt_problem = (
            first_attempt
        )
    episode.truncated = expert.truncated
    if error is not None:
        episode.outcome_problem = base.error_outcome(error.kind)
    return episode


def explore(
    env: Any, seed: int, env_index: int | None = None, frames: bool = True, segments: int = 4
) -> Episode:
    """The arm visits `segments` random points of the task's `explore_region`, opening or
    closing the gripper at random, instead of doing the task.

    In the experts' episodes the arm heads for the task objects, so where the arm is already
    tells where they are: a scene encoder trained on those frames alone learned to read the
    objects' positions off the arm's. These frames, labelled by the env states like any other,
    break that shortcut. Resets with `seed` (and `env_index`); `frames` as in `solve`.
    """
    base = env.unwrapped
    obs, _ = env.reset(seed=seed, options={} if env_index is None else {"env_index": env_index})
    rng = np.random.default_rng([seed, 2])
    expert = ScriptedExpert(env, rng, float(rng.uniform(0.015, 0.03)), keep_observations=frames)
    x0, x1, y0, y1, z0, z1 = base.explore_region
    try:
        for _ in range(segments):
            expert.gripper = OPEN if rng.random() < 0.5 else CLOSED
            expert.move_to(rng.uniform([x0, y0, z0], [x1, y1, z1]), settle=0)
    except EpisodeOver:
        pass
    episode = _episode(base, seed, None, expert, obs)
    episode.explore, episode.truncated = True, expert.truncated
    return episode


def _first_attempt_problem(base: Any, expert: ScriptedExpert, kind: str) -> str:
    """'' when a sub-optimal demonstration's first attempt failed, in its named way, else why
    not."""
    if any(expert.success):
        return "the first attempt succeeded"
    return base.error_outcome(kind)


def _episode(
    base: Any, seed: int, error: ErrorSpec | None, expert: ScriptedExpert, first_obs: Any
) -> Episode:
    steps = expert.steps
    labels = np.zeros(steps, dtype=np.uint8)
    if expert.onset is not None:
        labels[expert.onset :] = 1
    rgb: dict[str, np.ndarray] = {}
    depth: dict[str, np.ndarray] = {}
    if expert.keep_observations and isinstance(first_obs, dict) and "sensor_data" in first_obs:
        frames = [first_obs, *expert.observations]
        for camera, data in first_obs["sensor_data"].items():
            if "rgb" in data:
                rgb[camera] = np.stack(
                    [_to_numpy(o["sensor_data"][camera]["rgb"][0]) for o in frames]
                )
            if "depth" in data:
                depth[camera] = np.stack(
                    [_to_numpy(o["sensor_data"][camera]["depth"][0]) for o in frames]
                )
    return Episode(
        env_id=base.spec.id if base.spec is not None else f"AED-{base.task_name}-{base.split}",
        task=base.task_name,
        split=base.split,
        env_index=base.env_index,
        seed=seed,
        demonstrator=base.demonstrator,
        control_mode=base.control_mode,
        actions=np.asarray(expert.actions, dtype=np.float32).reshape(-1, 4),
        success=np.asarray(expert.success, dtype=bool),
        fail=np.asarray(expert.fail, dtype=bool),
        stage=np.asarray(expert.stage, dtype=np.int16),
        error_label=labels,
        error_kind=None if error is None else error.kind,
        error_onset=expert.onset,
        rgb=rgb,
        depth=depth,
        expert_speed=expert.speed,
    )


# --- the departure check -------------------------------------------------------------------
DEPARTURE_SAME = 1e-4  # metres: "the same" before the onset (the sim is deterministic: ~0)
DEPARTURE_APART = 0.005  # metres: "measurably different" after it
DEPARTURE_WINDOW = 5  # steps after the onset within which the episodes must differ


@dataclass
class Trace:
    """Per step: the action (T, 4) and, after it, the TCP position and the positions of every
    part of the task's objects (actors, and every link of articulations: a drawer's panel, a
    button's cap), as `points` (T, P, 3), the TCP first."""

    actions: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)


def trace_episode(
    env: Any, seed: int, error: ErrorSpec | None = None, env_index: int | None = None
) -> tuple[Episode, Trace]:
    """`solve()` the episode while recording its `Trace` (for `departure`)."""
    import gymnasium as gym

    class _Recorder(gym.Wrapper):
        def __init__(self, inner: Any):
            super().__init__(inner)
            self.points: list[np.ndarray] = []
            self.actions: list[np.ndarray] = []

        def step(self, action: Any):
            result = self.env.step(action)
            self.points.append(_task_points(self.env.unwrapped))
            self.actions.append(np.asarray(action, dtype=np.float64).reshape(-1))
            return result

    recorder = _Recorder(env)
    episode = solve(recorder, seed, error, env_index)
    return episode, Trace(np.asarray(recorder.actions).reshape(-1, 4), np.asarray(recorder.points))


def _task_points(base: Any) -> np.ndarray:
    points = [_to_numpy(base.agent.tcp.pose.p[0])]
    for entity in base.state_entities().values():
        links = entity.get_links() if hasattr(entity, "get_links") else [entity]
        points += [_to_numpy(link.pose.p[0]) for link in links]
    return np.asarray(points, dtype=np.float64)


@dataclass
class Departure:
    """How an intervened episode compares with the clean one of the same seed.

    `before`: the largest distance (m) of any point, or of any commanded TCP motion, before
    the onset (should be 0: the sim is deterministic); `acts`: whether the action at the onset
    differs (the intervention starts there, not earlier); `after`: steps from the onset to the
    first step where a point is more than `DEPARTURE_APART` away or the gripper command differs
    (None: not within the window).
    """

    onset: int
    before: float
    acts: bool
    after: int | None

    @property
    def problem(self) -> str:
        """'' when the labels mark the visible departure, else why not."""
        if self.before > DEPARTURE_SAME:
            return f"differs by {self.before * 1000:.2f} mm before the onset (step {self.onset})"
        if not self.acts:
            return f"the action at the onset (step {self.onset}) is the clean expert's"
        if self.after is None:
            return (
                f"no measurable difference within {DEPARTURE_WINDOW} steps of the onset "
                f"(step {self.onset})"
            )
        return ""


def departure(
    clean: Trace, intervened: Trace, onset: int, window: int = DEPARTURE_WINDOW
) -> Departure:
    """Compare an intervened episode's trace with the clean one's around `onset`.

    Step t of a trace is the state after action t, so action `onset` (the first intervened
    one) shows first at index `onset`; everything before must be the same.
    """
    if clean.points.shape[1:] != intervened.points.shape[1:]:
        raise ValueError(
            f"traces of different scenes: {clean.points.shape} vs {intervened.points.shape}"
        )
    if not 0 <= onset < len(intervened):
        raise ValueError(f"onset {onset} outside the intervened episode of {len(intervened)} steps")
    n = min(len(clean), len(intervened))
    gap = np.linalg.norm(clean.points[:n] - intervened.points[:n], axis=-1).max(axis=-1)
    moves = np.linalg.norm(clean.actions[:n, :3] - intervened.actions[:n, :3], axis=-1) * MAX_DELTA
    gripper_differs = clean.actions[:n, 3] != intervened.actions[:n, 3]
    before = float(max(gap[:onset].max(initial=0.0), moves[:onset].max(initial=0.0)))
    before = before if not gripper_differs[:onset].any() else float("inf")
    acts = onset >= n or bool(moves[onset] > 1e-6 or gripper_differs[onset])
    apart = (gap > DEPARTURE_APART) | gripper_differs
    # a clean episode that ended while the intervened one goes on has departed too
    after = next((k for k in range(window + 1) if onset + k >= n or apart[onset + k]), None)
    return Departure(onset, before, acts, after)

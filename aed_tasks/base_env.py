"""The shared base of every AED task: catalogues, room, cameras, demonstrator, info.

A task subclasses `AEDBaseEnv`, declares its catalogue sizes, stages and error kinds,
and fills these hooks (ManiSkill's own `BaseEnv` hooks are implemented here and call them):

- `sample_objects`: what an environment of the catalogue holds (no ManiSkill counterpart);
- `_load_task`: build those objects, called from ManiSkill's `_load_scene` after the room;
- `_initialize_task`: randomise their poses, called from ManiSkill's `_initialize_episode`
  after the robot is reset;
- `evaluate`: ManiSkill's own hook (success / fail / stage);
- `expert_script`: the motion-planned expert with its error injections.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np
import sapien
import torch
from mani_skill.agents.robots import Panda
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.structs import Actor, Articulation
from mani_skill.utils.structs.pose import Pose

from aed_tasks.catalogue import (
    Catalogue,
    EnvironmentSpec,
    ObjectSpec,
    catalogue_rng,
    check_split,
    sample_background,
    sample_distractors,
    sample_lighting,
)
from aed_tasks.rendering import camera_shader_config, use_minimal_picture_formats
from aed_tasks.scene import add_lights, build_distractor, build_room, rotation_z

if TYPE_CHECKING:
    from aed_tasks.expert import ErrorSpec, ScriptedExpert

ROBOT_BASE = (-0.615, 0.0, 0.0)
# Rest pose: the hand points down with its TCP 0.36 m in front of the base and 0.35 m up,
# behind and above every task object, so that neither camera sees it in front of one at reset.
REST_QPOS = np.array([0.0, -0.6, 0.0, -2.6, 0.0, 2.0, np.pi / 4, 0.04, 0.04])
# Camera poses (eye, target): `front` faces the robot across the table; `front_shift` is the
# viewpoint-change experiment's camera, moved back, sideways and up, away from the table.
CAMERAS: dict[str, tuple[list[float], list[float]]] = {
    "front": ([0.62, 0.0, 0.62], [-0.12, 0.0, 0.02]),
    "front_shift": ([0.82, 0.32, 0.78], [-0.12, 0.0, 0.02]),
}
IMAGE_WIDTH, IMAGE_HEIGHT = 160, 120
DEMONSTRATOR_TINT = (
    0.6,
    0.9,
    0.1,
    1.0,
)  # the expert's Panda is lime (no split colour), the agent's stays white


class AEDBaseEnv(BaseEnv):
    """Base of the AED tasks (a ManiSkill `BaseEnv`), one Panda at a table in a room.

    Args:
        split: "base" (training environments) or "novel" (deployment environments).
        env_index: pin one environment of the split's catalogue; by default each
            reconfiguring reset samples one (`reset(options={"env_index": k})` also pins).
        demonstrator: render the expert's appearance (a recoloured Panda) instead of the agent's.
        cameras: which of `front` and `front_shift` to render as sensors.
        shadows: directional shadows of the key light (on by default, as in the paper).
        terminate_on_success: end the episode (`terminated`) on the first success step, as
            ManiSkill does; with False only an irrecoverable failure terminates. Either way
            `info["success"]` is latched: once the task succeeded it stays True until reset.

    One env per process: the tasks build and randomise a single scene, so `num_envs` must be 1.
    """

    SUPPORTED_ROBOTS: ClassVar[list[str]] = ["panda"]
    SUPPORTED_REWARD_MODES: ClassVar[tuple[str, ...]] = (
        "sparse",
        "dense",
        "normalized_dense",
        "none",
    )
    agent: Panda

    # --- declared by each task ------------------------------------------------------------
    task_name: ClassVar[str] = ""
    catalogue_sizes: ClassVar[dict[str, int]] = {}
    num_stages: ClassVar[int] = 1
    error_kinds: ClassVar[tuple[str, ...]] = ()
    # errors after which the clean script, re-run from the current state, still succeeds:
    # the failed first attempts of sub-optimal demonstrations
    recoverable_errors: ClassVar[tuple[str, ...]] = ()
    num_env_distractors: ClassVar[int] = 0
    max_episode_steps: ClassVar[int] = (
        200  # the registered time limit: no expert episode reaches it
    )
    # steps of every policy rollout (aed rollout), whatever its outcome, so that its length tells
    # nothing: twice the longest clean expert episode (imitating policies are slower than the
    # expert), at most the time limit; results/expert_lengths/ has the lengths
    eval_horizon: ClassVar[int] = 200
    # where exploration episodes send the TCP (`aed_tasks.expert.explore`): x0, x1, y0, y1 on
    # the table top (robot base frame) and z0, z1 above it, covering every task's objects
    explore_region: ClassVar[tuple[float, ...]] = (-0.3, 0.15, -0.3, 0.3, 0.03, 0.25)

    def __init__(
        self,
        *args: Any,
        split: str = "base",
        env_index: int | None = None,
        demonstrator: bool = False,
        cameras: tuple[str, ...] = ("front",),
        shadows: bool = True,
        robot_uids: str = "panda",
        robot_init_qpos_noise: float = 0.02,
        terminate_on_success: bool = True,
        **kwargs: Any,
    ):
        num_envs = kwargs.get("num_envs", args[0] if args else 1)
        if num_envs != 1:
            raise ValueError(
                f"num_envs={num_envs}: AED tasks run one env per process; "
                "use separate processes (aed collect --workers N)"
            )
        self.split = check_split(split)
        self.catalogue = self.get_catalogue(split)
        if env_index is not None:
            self.catalogue[env_index]  # raises a clear IndexError when out of range
        unknown = set(cameras) - set(CAMERAS)
        if unknown or not cameras:
            raise ValueError(f"unknown cameras {sorted(unknown)}; known: {sorted(CAMERAS)}")
        self.pinned_env_index = env_index
        self.demonstrator = demonstrator
        self.camera_names = tuple(cameras)
        self.robot_init_qpos_noise = robot_init_qpos_noise
        self.terminate_on_success = bool(terminate_on_success)
        self._succeeded = torch.zeros(1, dtype=torch.bool)  # the latch, reset with each episode
        self.env_spec: EnvironmentSpec = self.catalogue[env_index or 0]
        self._requested_env_index: int | None = None
        kwargs.setdefault("obs_mode", "rgbd")
        kwargs.setdefault("control_mode", "pd_ee_delta_pos")
        super().__init__(*args, robot_uids=robot_uids, enable_shadow=shadows, **kwargs)

    # --- catalogue ------------------------------------------------------------------------
    @classmethod
    @cache
    def get_catalogue(cls, split: str) -> Catalogue:
        """The task's fixed environments of one split (built once, deterministically)."""
        check_split(split)
        if split not in cls.catalogue_sizes:
            raise ValueError(f"{cls.__name__} declares no catalogue size for split {split!r}")
        envs = tuple(cls.make_environment(split, i) for i in range(cls.catalogue_sizes[split]))
        return Catalogue(cls.task_name, split, envs)

    @classmethod
    def make_environment(cls, split: str, index: int) -> EnvironmentSpec:
        rng = catalogue_rng(cls.task_name, split, index)
        objects = cls.sample_objects(rng, split, index)
        ambient, lights = sample_lighting(rng)
        used = [o.material.colour for o in objects.values()]
        distractors = sample_distractors(rng, split, cls.num_env_distractors, exclude=used)
        return EnvironmentSpec(
            task=cls.task_name,
            split=split,
            index=index,
            ambient=ambient,
            lights=lights,
            objects=objects,
            distractors=distractors,
            **sample_background(rng, split),
        )

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        """The task's interactive objects and task distractors of environment `index`."""
        raise NotImplementedError

    @property
    def env_index(self) -> int:
        return self.env_spec.index

    # --- scene ----------------------------------------------------------------------------
    @property
    def _default_sensor_configs(self) -> list[CameraConfig]:
        shader = camera_shader_config()  # `minimal` with a shadow filter cheap on CPUs
        return [
            CameraConfig(
                name,
                sapien_utils.look_at(*CAMERAS[name]),
                IMAGE_WIDTH,
                IMAGE_HEIGHT,
                np.deg2rad(62),
                0.01,
                5,
                shader_config=shader,
            )
            for name in self.camera_names
        ]

    def _setup_sensors(self, options: dict) -> None:
        use_minimal_picture_formats()  # ManiSkill sets them only for packs named "minimal"
        super()._setup_sensors(options)

    @property
    def _default_human_render_camera_configs(self) -> CameraConfig:
        return CameraConfig(
            "render_camera",
            sapien_utils.look_at(*CAMERAS["front"]),
            640,
            480,
            np.deg2rad(62),
            0.01,
            5,
        )

    def reset(self, seed: int | None = None, options: dict | None = None):
        """ManiSkill's reset, plus `options["env_index"]` (switch environment).

        A reset with an explicit seed rebuilds the scene (a few tenths of a second), so that a
        seed gives the same episode bit for bit: PhysX keeps contact caches across a plain
        reset, and an episode that ended in contact would nudge the next one.
        """
        options = dict(options or {})
        if "env_index" in options:
            index = options.pop("env_index")
            self.catalogue[index]
            self._requested_env_index = index
            options["reconfigure"] = True
        if isinstance(seed, int):
            options["reconfigure"] = True
        if seed is None or isinstance(seed, int):
            gym.Env.reset(self, seed=seed)  # Gymnasium's convention: seed `self.np_random` too
        return super().reset(seed=seed, options=options)

    def _choose_environment(self) -> EnvironmentSpec:
        if self._requested_env_index is not None:
            index, self._requested_env_index = self._requested_env_index, None
        elif self.pinned_env_index is not None:
            index = self.pinned_env_index
        else:
            index = int(self._batched_episode_rng[0].randint(len(self.catalogue)))
        return self.catalogue[index]

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=list(ROBOT_BASE)))

    def _load_scene(self, options: dict):
        self.env_spec = self._choose_environment()
        self.table = build_room(self.scene, self.env_spec)
        self.distractors: list[Actor] = [
            build_distractor(self.scene, spec, f"distractor_{i}")
            for i, spec in enumerate(self.env_spec.distractors)
        ]
        if self.demonstrator:
            recolour_robot(self.agent.robot, DEMONSTRATOR_TINT)
        self._load_task(options)

    def _load_lighting(self, options: dict):
        add_lights(self.scene, self.env_spec, shadows=self.enable_shadow)

    def _load_task(self, options: dict) -> None:
        """Build the task's objects from `self.env_spec.objects`."""
        raise NotImplementedError

    # --- episodes -------------------------------------------------------------------------
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        rng = np.random.default_rng(int(self._episode_seed[0]))
        qpos = REST_QPOS + rng.normal(0, self.robot_init_qpos_noise, len(REST_QPOS)) * (
            np.arange(9) < 7
        )
        self.agent.reset(torch.as_tensor(qpos, dtype=torch.float32)[None])
        self.agent.robot.set_pose(sapien.Pose(p=list(ROBOT_BASE)))
        self._succeeded = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        self._initialize_task(rng)

    def _initialize_task(self, rng: np.random.Generator) -> None:
        """Randomise the poses of the task's objects (and place the distractors)."""
        raise NotImplementedError

    def place_distractors(
        self,
        rng: np.random.Generator,
        region: tuple[float, float, float, float],
        keep_out: list[tuple[float, float, float]],
    ) -> None:
        """Put the environment distractors at free spots of `region` (x0, x1, y0, y1)."""
        for actor in self.distractors:
            x, y = sample_free_xy(rng, region, 0.05, keep_out)
            keep_out.append((x, y, 0.05))
            actor.set_pose(
                Pose.create_from_pq(p=[x, y, 0.001], q=rotation_z(rng.uniform(0, 2 * np.pi)))
            )

    # --- evaluation -----------------------------------------------------------------------
    def evaluate(self) -> dict[str, torch.Tensor]:
        """success, fail (irrecoverable) and stage (sub-goals completed so far)."""
        raise NotImplementedError

    def get_info(self) -> dict:
        """ManiSkill's info with `success` latched: the expert's retreat and rest after the
        task, and whatever a policy does next, leave a succeeded episode succeeded."""
        info = super().get_info()
        self._succeeded = self._succeeded | info["success"]
        info["success"] = self._succeeded.clone()
        return info

    def step(self, action: Any) -> tuple:
        obs, reward, terminated, truncated, info = super().step(action)
        if not self.terminate_on_success:
            terminated = info["fail"].clone()
        return obs, reward, terminated, truncated, info

    def objects_off_table(self, *actors: Actor) -> torch.Tensor:
        """True where any of the actors fell from the table (an irrecoverable failure)."""
        return torch.stack([a.pose.p[:, 2] < -0.1 for a in actors]).any(dim=0)

    def _get_obs_extra(self, info: dict) -> dict:
        obs = {"tcp_pose": self.agent.tcp.pose.raw_pose}
        if self.obs_mode_struct.state:
            for name, entity in self.state_entities().items():
                obs[f"{name}_pose"] = entity.pose.raw_pose
        return obs

    def state_entities(self) -> dict[str, Actor | Articulation]:
        """Objects whose poses state observations include (tasks override)."""
        return {}

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Stage progress: one per completed sub-goal, one more for success."""
        return info["stage"].float() + info["success"].float()

    def compute_normalized_dense_reward(
        self, obs: Any, action: torch.Tensor, info: dict
    ) -> torch.Tensor:
        return self.compute_dense_reward(obs, action, info) / (self.num_stages + 1)

    # --- expert ---------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        """Drive `expert` through the task; at the critical moment of `error`, deviate."""
        raise NotImplementedError

    def error_outcome(self, kind: str) -> str:
        """'' when the episode's state now shows the named failure `kind`, else why not.

        Tasks override this with a check of each kind's outcome (e.g. `closes_both` closed both
        drawers); this default accepts any unsuccessful ending.
        """
        if kind not in self.error_kinds:
            raise ValueError(
                f"unknown error kind {kind!r} for {self.task_name}; known: {list(self.error_kinds)}"
            )
        return "the task succeeded" if bool(self.get_info()["success"].any()) else ""


def sample_free_xy(
    rng: np.random.Generator,
    region: tuple[float, float, float, float],
    radius: float,
    keep_out: list[tuple[float, float, float]],
    tries: int = 200,
) -> tuple[float, float]:
    """A point of `region` at least `radius` + r away from every (x, y, r) of `keep_out`."""
    x0, x1, y0, y1 = region
    for _ in range(tries):
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if all(np.hypot(x - kx, y - ky) >= radius + kr for kx, ky, kr in keep_out):
            return float(x), float(y)
    raise RuntimeError(f"no free spot of radius {radius} in region {region} after {tries} tries")


def recolour_robot(robot: Articulation, colour: tuple[float, float, float, float]) -> None:
    """Tint every visual part of the robot: the demonstrator looks unlike the agent."""
    for link in robot.get_links():
        for obj in link._objs:
            body = obj.entity.find_component_by_type(sapien.render.RenderBodyComponent)
            if body is None:
                continue
            for shape in body.render_shapes:
                for part in shape.get_parts():
                    base = np.asarray(part.material.base_color)
                    # keep dark parts dark; light (white) parts take the tint
                    if base[:3].mean() > 0.5:
                        part.material.base_color = list(colour)

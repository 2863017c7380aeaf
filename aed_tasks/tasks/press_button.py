"""Press Button: fully press a spring-loaded push button placed somewhere on the table."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.base_env import AEDBaseEnv, sample_free_xy
from aed_tasks.catalogue import MaterialSpec, ObjectSpec, object_colours, pick
from aed_tasks.expert import ErrorSpec, ScriptedExpert
from aed_tasks.objects.button import (
    CAP_SHAPES,
    HOUSING_SHAPES,
    ButtonGeometry,
    build_button,
)
from aed_tasks.registration import register_task
from aed_tasks.scene import rotation_z

BUTTON_REGION = (-0.12, 0.10, -0.2, 0.2)  # x0, x1, y0, y1 on the table top
DISTRACTOR_REGION = (-0.3, 0.22, -0.34, 0.34)
HAND_CLEARANCE = 0.1  # distractors stay this far beyond the housing: the hand spans +-10 cm in y
FULL_PRESS_MARGIN = 0.002  # "fully pressed": the cap within this of the bottom of its travel
FINGERTIP_DROP = 0.009  # the closed fingertips reach this far below the TCP (measured)
OVERPRESS = 0.006  # the expert aims its fingertips this far below the end of the travel


@register_task
class PressButtonEnv(AEDBaseEnv):
    """
    **Task Description:**
    Fully press the push button, which stands somewhere in a designated area of the table,
    with the closed gripper's fingertips. Three unrelated objects clutter the table.

    **Randomizations:**
    - per environment: table, floor and wall textures, lighting, the button design
      (housing and cap shapes), its size, travel (1.5-2 cm), spring stiffness and colours
    - per episode: button position in a 22 x 40 cm region and its yaw, distractor poses

    **Success Conditions:**
    - the cap has reached the bottom of its travel (within 2 mm) at some step of the episode
      (latched: the spring pushes it back up once released)

    **Stages:** pressed (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `no_touch`: the gripper comes down beside the button and never touches it (the cap
      never moved by 1 mm)
    - `not_fully_pressed`: the press stops short, 35-65% of the travel down, then the gripper
      lets go (the cap went down at least 20% of its travel, never within 2 mm of the bottom);
      the onset is where the press stops, the clean press having been followed until then
    """

    task_name = "PressButton"
    catalogue_sizes = {"base": 27, "novel": 18}
    num_stages = 1
    error_kinds = ("no_touch", "not_fully_pressed")
    recoverable_errors = ("no_touch", "not_fully_pressed")
    num_env_distractors = 3
    max_episode_steps = 200
    eval_horizon = 200

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        cap_colour, housing_colour = pick(rng, object_colours(split), 2)
        cap_half = float(rng.uniform(0.022, 0.03))
        cap_size = (
            cap_half,
            float(rng.uniform(0.01, 0.015)),  # height
            float(rng.uniform(0.015, 0.02)),  # travel
            float(rng.uniform(250, 400)),  # spring stiffness (N/m)
        )
        housing_size = (
            float(rng.uniform(cap_half + 0.012, 0.055)),
            float(rng.uniform(0.022, 0.036)),
        )
        return {
            "button_housing": ObjectSpec(
                pick(rng, HOUSING_SHAPES[split]),
                housing_size,
                MaterialSpec(colour=housing_colour, roughness=0.6),
            ),
            "button_cap": ObjectSpec(
                pick(rng, CAP_SHAPES[split]),
                cap_size,
                MaterialSpec(colour=cap_colour, roughness=0.35),
            ),
        }

    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.geometry = ButtonGeometry.from_specs(objects["button_housing"], objects["button_cap"])
        self.button = build_button(
            self.scene, objects["button_housing"], objects["button_cap"], "button"
        )

    def _initialize_task(self, rng: np.random.Generator) -> None:
        g = self.geometry
        x, y = sample_free_xy(rng, BUTTON_REGION, 0.0, [])
        self.button.set_pose(
            Pose.create_from_pq(p=[x, y, 0.0], q=rotation_z(rng.uniform(0, 2 * np.pi)))
        )
        self.button.set_qpos(torch.zeros((self.num_envs, 1)))
        self.place_distractors(rng, DISTRACTOR_REGION, [(x, y, g.footprint + HAND_CLEARANCE)])
        self.pressed = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        self.deepest = torch.zeros(
            self.num_envs, device=self.device
        )  # the deepest press so far (m)

    # --- evaluation -------------------------------------------------------------------------
    def press_depth(self) -> torch.Tensor:
        """How far the cap is pushed down from rest (m), per env."""
        return -self.button.get_qpos()[:, 0].to(self.device)

    def evaluate(self) -> dict[str, torch.Tensor]:
        depth = self.press_depth()
        self.pressed = self.pressed | (depth >= self.geometry.travel - FULL_PRESS_MARGIN)
        self.deepest = torch.maximum(self.deepest, depth)
        return {
            "success": self.pressed.clone(),
            "fail": torch.zeros_like(self.pressed),
            "stage": self.pressed.to(torch.int32),
            "press_depth": depth,
        }

    def state_entities(self) -> dict:
        return {"button": self.button}

    def _get_obs_extra(self, info: dict) -> dict:
        obs = super()._get_obs_extra(info)
        if self.obs_mode_struct.state:
            obs["button_depth"] = self.press_depth()[:, None]
        return obs

    # --- expert -----------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        kind = error.kind if error else None
        g = self.geometry
        centre = self.button.pose.p[0].cpu().numpy().astype(np.float64)
        top = centre + np.array([0.0, 0.0, g.cap_top])
        hover = top + np.array([0.0, 0.0, expert.rng.uniform(0.07, 0.13)])

        expert.close_gripper(steps=int(expert.rng.integers(4, 9)))
        expert.move_to(hover + expert.jitter(0.02))
        if kind == "no_touch":  # come down beside the button, clear of housing and cap
            expert.mark_error()
            expert.move_to(self._beside(centre, top, g, expert), speed=expert.speed * 0.6)
            expert.wait(int(expert.rng.integers(3, 8)))
            expert.move_by([0.0, 0.0, expert.rng.uniform(0.06, 0.1)])
            expert.wait(4)
            return
        contact = (
            top
            + np.array([0.0, 0.0, FINGERTIP_DROP + expert.rng.uniform(0.008, 0.02)])
            + expert.jitter(0.004)
        )
        expert.move_to(contact, speed=expert.speed * 0.6)
        press = np.array([contact[0], contact[1], top[2] + FINGERTIP_DROP - g.travel - OVERPRESS])
        stop_before = None
        if kind == "not_fully_pressed":  # press as the clean expert does, stop part of the way down
            partial = g.travel * expert.error_rng.uniform(0.35, 0.65) - expert.speed * 0.35 / 2

            def stop_before(waypoint: np.ndarray) -> bool:  # the cap is part of the way down
                return float(self.press_depth()[0]) >= partial

        if expert.move_to(press, speed=expert.speed * 0.35, tol=0.003, stop_before=stop_before):
            expert.mark_error()  # the press stops here: the clean expert would go on down
        expert.wait(int(expert.rng.integers(2, 6)))
        expert.move_by([0.0, 0.0, expert.rng.uniform(0.06, 0.1)])
        expert.wait(4)

    def error_outcome(self, kind: str) -> str:
        super().error_outcome(kind)
        deepest, travel = float(self.deepest[0]), self.geometry.travel
        if bool(self.pressed[0]):
            return f"the cap reached the bottom of its travel ({deepest * 1000:.1f} mm)"
        if kind == "no_touch" and deepest >= 0.001:
            return f"the cap was pushed {deepest * 1000:.1f} mm"
        if kind == "not_fully_pressed" and deepest < 0.2 * travel:
            return f"the cap went down only {deepest * 1000:.1f} mm of {travel * 1000:.1f}"
        return ""

    @staticmethod
    def _beside(
        centre: np.ndarray, top: np.ndarray, g: ButtonGeometry, expert: ScriptedExpert
    ) -> np.ndarray:
        """A spot next to the button, a few cm off its footprint, toward the robot or away from
        it."""
        far = (
            centre[0] > 0.0
        )  # beyond the button, a low spot is hard to reach: come toward the robot
        side = -1.0 if far else np.sign(expert.rng.uniform(-1, 1))
        offset = g.footprint + expert.rng.uniform(0.035, 0.05)
        height = g.housing_height + FINGERTIP_DROP + expert.rng.uniform(0.0, 0.015)
        return np.array(
            [centre[0] + side * offset, top[1] + expert.rng.uniform(-0.01, 0.01), height]
        )

"""Pick & Place: put the mug (or cup) into the bowl the demonstrations chose."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.base_env import AEDBaseEnv, sample_free_xy
from aed_tasks.catalogue import MaterialSpec, ObjectSpec, object_colours, pick
from aed_tasks.expert import ErrorSpec, ScriptedExpert
from aed_tasks.objects.vessels import build_bowl, build_vessel
from aed_tasks.registration import register_task
from aed_tasks.scene import rotation_z

VESSEL_SHAPES = {"base": ("mug_cylinder", "cup_tapered"), "novel": ("mug_barrel", "cup_waisted")}
BOWL_SHAPES = {"base": ("bowl_round", "bowl_straight"), "novel": ("bowl_basin", "bowl_lipped")}
MUG_REGION = (-0.22, -0.08, -0.22, 0.22)  # x0, x1, y0, y1 on the table top
BOWL_REGION = (-0.02, 0.14, -0.26, 0.26)


@register_task
class PickPlaceEnv(AEDBaseEnv):
    """
    **Task Description:**
    Pick up the mug (or cup) and place it into the bowl that the expert used in the
    demonstrations; a second bowl of another colour is a task distractor.

    **Randomizations:**
    - per environment: table, floor and wall textures, lighting, vessel shape, size and
      colour, bowl shapes, sizes and colours (target and distractor differ in colour)
    - per episode: mug position in a 14 x 44 cm region and its yaw (handle away from the
      fingers), both bowl positions (which side the target is on varies)

    **Success Conditions:**
    - the mug rests inside the target bowl, released by the gripper

    **Stages:** picked (lifted while grasped), placed (success).

    **Behaviour Errors:**
    - `no_grasp`: the gripper closes beside the mug; it is never picked up
    - `miss_place`: the mug is released away from the target bowl
    - `wrong_bowl`: the mug is placed into the distractor bowl
    """

    task_name = "PickPlace"
    catalogue_sizes = {"base": 90, "novel": 42}
    num_stages = 2
    error_kinds = ("no_grasp", "miss_place", "wrong_bowl")
    recoverable_errors = ("no_grasp", "miss_place")
    max_episode_steps = 250

    @classmethod
    def sample_objects(cls, rng: np.random.Generator, split: str, index: int) -> dict[str, ObjectSpec]:
        vessel_colour, target_colour, distractor_colour = pick(rng, object_colours(split), 3)
        bowl_shape = pick(rng, BOWL_SHAPES[split])
        bowl_size = (float(rng.uniform(0.15, 0.18)), float(rng.uniform(0.045, 0.06)))
        return {
            "vessel": ObjectSpec(
                pick(rng, VESSEL_SHAPES[split]),
                (float(rng.uniform(0.052, 0.062)), float(rng.uniform(0.075, 0.095))),
                MaterialSpec(colour=vessel_colour, roughness=0.4),
            ),
            "target_bowl": ObjectSpec(bowl_shape, bowl_size, MaterialSpec(colour=target_colour, roughness=0.5)),
            "distractor_bowl": ObjectSpec(
                pick(rng, BOWL_SHAPES[split]),
                (float(rng.uniform(0.15, 0.18)), float(rng.uniform(0.045, 0.06))),
                MaterialSpec(colour=distractor_colour, roughness=0.5),
            ),
        }

    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.vessel = build_vessel(self.scene, objects["vessel"], "vessel")
        self.target_bowl = build_bowl(self.scene, objects["target_bowl"], "target_bowl")
        self.distractor_bowl = build_bowl(self.scene, objects["distractor_bowl"], "distractor_bowl")

    def _initialize_task(self, rng: np.random.Generator) -> None:
        keep_out: list[tuple[float, float, float]] = []
        for bowl, key in ((self.target_bowl, "target_bowl"), (self.distractor_bowl, "distractor_bowl")):
            radius = self.env_spec.objects[key].size[0] / 2
            x, y = sample_free_xy(rng, BOWL_REGION, radius + 0.02, keep_out)
            keep_out.append((x, y, radius))
            bowl.set_pose(Pose.create_from_pq(p=[x, y, 0.001]))
        x, y = sample_free_xy(rng, MUG_REGION, 0.06, keep_out)
        yaw = rng.uniform(-0.5, 0.5) + (np.pi if rng.random() < 0.5 else 0.0)
        self.vessel.set_pose(Pose.create_from_pq(p=[x, y, 0.001], q=rotation_z(yaw)))
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)

    # --- evaluation -------------------------------------------------------------------------
    def _in_bowl(self, bowl_key: str) -> torch.Tensor:
        bowl = self.target_bowl if bowl_key == "target_bowl" else self.distractor_bowl
        diameter, height = self.env_spec.objects[bowl_key].size
        offset = self.vessel.pose.p - bowl.pose.p
        inside_xy = torch.linalg.norm(offset[:, :2], dim=1) < diameter * 0.3
        resting = offset[:, 2] < height * 0.6
        return inside_xy & resting

    def evaluate(self) -> dict[str, torch.Tensor]:
        grasped = self.agent.is_grasping(self.vessel)
        lifted = self.vessel.pose.p[:, 2] > 0.03
        placed = self._in_bowl("target_bowl") & ~grasped
        stage = torch.where(placed, 2, torch.where(grasped & lifted, 1, 0)).to(torch.int32)
        self.stage_reached = torch.maximum(self.stage_reached, stage)
        return {
            "success": placed,
            "fail": self.objects_off_table(self.vessel),
            "stage": self.stage_reached.clone(),
            "is_grasped": grasped,
        }

    def state_entities(self) -> dict:
        return {"vessel": self.vessel, "target_bowl": self.target_bowl, "distractor_bowl": self.distractor_bowl}

    # --- expert -----------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        kind = error.kind if error else None
        mug = self.vessel.pose.p[0].numpy().astype(np.float64)
        diameter, height = self.env_spec.objects["vessel"].size
        grasp = mug + np.array([0.0, 0.0, height * 0.55])
        hover = grasp + np.array([0.0, 0.0, expert.rng.uniform(0.08, 0.14)])

        expert.move_to(hover + expert.jitter(0.02))
        if kind == "no_grasp":  # close the fingers beside the mug instead of around it
            expert.mark_error()
            side = np.array([0.0, np.sign(expert.rng.uniform(-1, 1)) * (diameter / 2 + 0.035), 0.0])
            expert.move_to(grasp + side, speed=expert.speed * 0.6)
        else:
            expert.move_to(grasp, speed=expert.speed * 0.6)
        expert.close_gripper()
        lift = expert.rng.uniform(0.12, 0.18)
        expert.move_to(expert.tcp + np.array([0.0, 0.0, lift]), speed=expert.speed * 0.7)

        bowl_key = "distractor_bowl" if kind == "wrong_bowl" else "target_bowl"
        bowl = (self.distractor_bowl if bowl_key == "distractor_bowl" else self.target_bowl).pose.p[0].numpy()
        bowl_height = self.env_spec.objects[bowl_key].size[1]
        release = np.array([bowl[0], bowl[1], bowl_height + height * 0.55 + 0.02])
        if kind == "wrong_bowl":
            expert.mark_error()
        elif kind == "miss_place":  # drop it short of the bowl, on the table
            expert.mark_error()
            away = release[:2] - expert.tcp[:2]
            release[:2] -= away / max(np.linalg.norm(away), 1e-6) * expert.rng.uniform(0.13, 0.17)
            release[2] = height * 0.55 + 0.03
        expert.move_to(np.array([release[0], release[1], expert.tcp[2]]) + expert.jitter(0.015))
        expert.move_to(release, speed=expert.speed * 0.6)
        expert.open_gripper()
        expert.move_by([0.0, 0.0, 0.08])
        expert.wait(4)

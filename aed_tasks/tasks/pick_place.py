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
IN_BOWL_RADIUS = 0.3  # the mug is in a bowl with its centre within this fraction of the diameter
IN_BOWL_HEIGHT = 0.6  # ... and its base below this fraction of the bowl's height above it
AT_REST_SPEED = 0.02  # m/s: the mug is at rest (settled) below this linear speed
AT_REST_SPIN = 0.3  # rad/s: ... and below this angular speed
UPRIGHT_TILT = 25.0  # degrees: the mug is upright with its axis within this of vertical
LIFTED = 0.03  # m: the mug is lifted with its base this high
UNTOUCHED = 0.01  # m: `no_grasp` leaves the mug within this of its start (it never moved)
FINGER_REACH = 0.05  # m: an open finger's outer face from the TCP along the finger axis (y)
REACH_Y = 0.26  # m: the top-down gripper comes down easily within this of the robot's axis


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
    - the mug is settled inside the target bowl, released by the gripper: its centre within
      0.3 bowl diameters of the bowl's axis, its base below 0.6 bowl heights above the bowl's,
      at rest (below 2 cm/s and 0.3 rad/s) and upright (axis within 25 degrees of vertical)

    **Stages:** picked (lifted while grasped), placed (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `no_grasp`: the gripper comes down beside the mug, both fingers clear of it (the open
      fingers' outer faces 1.5-2.5 cm off its side, on the side away from the bowls) and
      closes on nothing (checked: the mug was never lifted nor moved by 1 cm)
    - `miss_place`: the transport to the target bowl stops 13-17 cm short of the bowl's centre
      and the mug is released there, on the table (checked: released, its centre outside both
      bowls' rims); the onset is where the transport stops
    - `wrong_bowl`: the mug is placed into the distractor bowl (checked: settled there as a
      success would be in the target bowl)
    """

    task_name = "PickPlace"
    catalogue_sizes = {"base": 90, "novel": 42}
    num_stages = 2
    error_kinds = ("no_grasp", "miss_place", "wrong_bowl")
    recoverable_errors = ("no_grasp", "miss_place")
    max_episode_steps = 250
    eval_horizon = 250

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        vessel_colour, target_colour, distractor_colour = pick(rng, object_colours(split), 3)
        bowl_shape = pick(rng, BOWL_SHAPES[split])
        bowl_size = (float(rng.uniform(0.15, 0.18)), float(rng.uniform(0.045, 0.06)))
        return {
            "vessel": ObjectSpec(
                pick(rng, VESSEL_SHAPES[split]),
                (float(rng.uniform(0.052, 0.062)), float(rng.uniform(0.075, 0.095))),
                MaterialSpec(colour=vessel_colour, roughness=0.4),
            ),
            "target_bowl": ObjectSpec(
                bowl_shape, bowl_size, MaterialSpec(colour=target_colour, roughness=0.5)
            ),
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
        for bowl, key in (
            (self.target_bowl, "target_bowl"),
            (self.distractor_bowl, "distractor_bowl"),
        ):
            radius = self.env_spec.objects[key].size[0] / 2
            x, y = sample_free_xy(rng, BOWL_REGION, radius + 0.02, keep_out)
            keep_out.append((x, y, radius))
            bowl.set_pose(Pose.create_from_pq(p=[x, y, 0.001]))
        x, y = sample_free_xy(rng, MUG_REGION, 0.06, keep_out)
        yaw = rng.uniform(-0.5, 0.5) + (np.pi if rng.random() < 0.5 else 0.0)
        self.vessel.set_pose(Pose.create_from_pq(p=[x, y, 0.001], q=rotation_z(yaw)))
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)
        self.vessel_start = self.vessel.pose.p.clone()
        self.vessel_travel = torch.zeros(
            self.num_envs, device=self.device
        )  # farthest from the start so far

    # --- evaluation -------------------------------------------------------------------------
    def _in_bowl(self, bowl_key: str) -> torch.Tensor:
        """The mug is settled in the bowl: inside it, at rest and upright."""
        bowl = self.target_bowl if bowl_key == "target_bowl" else self.distractor_bowl
        diameter, height = self.env_spec.objects[bowl_key].size
        offset = self.vessel.pose.p - bowl.pose.p
        inside_xy = torch.linalg.norm(offset[:, :2], dim=1) < diameter * IN_BOWL_RADIUS
        low = offset[:, 2] < height * IN_BOWL_HEIGHT
        return inside_xy & low & self._settled()

    def _settled(self) -> torch.Tensor:
        still = torch.linalg.norm(self.vessel.linear_velocity, dim=1) < AT_REST_SPEED
        still &= torch.linalg.norm(self.vessel.angular_velocity, dim=1) < AT_REST_SPIN
        upright = self.vessel.pose.to_transformation_matrix()[:, 2, 2] > np.cos(
            np.deg2rad(UPRIGHT_TILT)
        )
        return still & upright

    def evaluate(self) -> dict[str, torch.Tensor]:
        grasped = self.agent.is_grasping(self.vessel)
        lifted = self.vessel.pose.p[:, 2] > LIFTED
        moved = torch.linalg.norm(self.vessel.pose.p - self.vessel_start, dim=1)
        self.vessel_travel = torch.maximum(self.vessel_travel, moved)
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
        return {
            "vessel": self.vessel,
            "target_bowl": self.target_bowl,
            "distractor_bowl": self.distractor_bowl,
        }

    def error_outcome(self, kind: str) -> str:
        super().error_outcome(kind)
        info = self.evaluate()
        if bool(info["is_grasped"][0]):
            return "the gripper still holds the mug"
        mug = self.vessel.pose.p[0].cpu().numpy()
        if kind == "no_grasp":
            travel = float(self.vessel_travel[0])
            return "" if travel < UNTOUCHED else f"the mug moved by {travel * 100:.1f} cm"
        if kind == "wrong_bowl":
            return (
                ""
                if bool(self._in_bowl("distractor_bowl")[0])
                else "the mug is not settled in the distractor bowl"
            )
        for bowl, key in (
            (self.target_bowl, "target_bowl"),
            (self.distractor_bowl, "distractor_bowl"),
        ):
            distance = float(np.linalg.norm(mug[:2] - bowl.pose.p[0, :2].cpu().numpy()))
            if distance < self.env_spec.objects[key].size[0] / 2:
                return (
                    f"the mug is {distance * 100:.1f} cm from the centre of the "
                    f"{key.replace('_', ' ')}"
                )
        return ""

    # --- expert -----------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        kind = error.kind if error else None
        mug = self.vessel.pose.p[0].cpu().numpy().astype(np.float64)
        diameter, height = self.env_spec.objects["vessel"].size
        grasp = mug + np.array([0.0, 0.0, height * 0.55])
        hover = grasp + np.array([0.0, 0.0, expert.rng.uniform(0.08, 0.14)])

        expert.move_to(hover + expert.jitter(0.02))
        if (
            kind == "no_grasp"
        ):  # move aside, then come down beside the mug, both fingers clear of it
            expert.mark_error()
            side = self._clear_side(
                mug, diameter / 2 + FINGER_REACH + expert.error_rng.uniform(0.015, 0.025)
            )
            expert.move_to(
                np.array([grasp[0], grasp[1] + side, expert.tcp[2]]), speed=expert.speed * 0.6
            )
            expert.move_to(grasp + np.array([0.0, side, 0.0]), speed=expert.speed * 0.6)
        else:
            expert.move_to(grasp, speed=expert.speed * 0.6)
        expert.close_gripper()
        lift = expert.rng.uniform(0.12, 0.18)
        expert.move_to(expert.tcp + np.array([0.0, 0.0, lift]), speed=expert.speed * 0.7)

        bowl_key = "distractor_bowl" if kind == "wrong_bowl" else "target_bowl"
        bowl = (
            (self.distractor_bowl if bowl_key == "distractor_bowl" else self.target_bowl)
            .pose.p[0]
            .cpu()
            .numpy()
        )
        bowl_height = self.env_spec.objects[bowl_key].size[1]
        release = np.array([bowl[0], bowl[1], bowl_height + height * 0.55 + 0.02])
        if kind == "wrong_bowl":
            expert.mark_error()
        stop_before = None
        if kind == "miss_place":  # head for the target bowl as the clean expert does, stop short
            short = expert.error_rng.uniform(0.13, 0.17)
            stop_before = lambda waypoint: np.linalg.norm(waypoint[:2] - bowl[:2]) < short  # noqa: E731
        above = np.array([release[0], release[1], expert.tcp[2]]) + expert.jitter(0.015)
        if expert.move_to(above, stop_before=stop_before):
            expert.mark_error()  # the transport stops here: the mug goes down on the table
            release = np.array([*expert.tcp[:2], height * 0.55 + 0.015])
        expert.move_to(release, speed=expert.speed * 0.6)
        expert.open_gripper()
        expert.move_by([0.0, 0.0, 0.08])
        expert.wait(4)

    def _clear_side(self, mug: np.ndarray, offset: float) -> float:
        """`offset` toward the side (+-y) of the mug where the open gripper is farthest from the
        bowls, within the arm's easy reach (|y| < REACH_Y) where that side is."""
        bowls = [
            (
                self.target_bowl.pose.p[0, :2].cpu().numpy(),
                self.env_spec.objects["target_bowl"].size[0] / 2,
            ),
            (
                self.distractor_bowl.pose.p[0, :2].cpu().numpy(),
                self.env_spec.objects["distractor_bowl"].size[0] / 2,
            ),
        ]

        def clearance(sign: float) -> float:
            hand = mug[:2] + np.array([0.0, sign * offset])
            return min(float(np.linalg.norm(hand - centre)) - radius for centre, radius in bowls)

        sides = [sign for sign in (1.0, -1.0) if abs(mug[1] + sign * offset) < REACH_Y]
        if not sides:
            return -np.sign(mug[1]) * offset
        return max(sides, key=clearance) * offset

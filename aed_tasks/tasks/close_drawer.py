"""Close Drawer: push shut the drawer the demonstrations closed, leave the other one alone."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.base_env import AEDBaseEnv
from aed_tasks.catalogue import MaterialSpec, ObjectSpec, object_colours, pick, sample_material
from aed_tasks.expert import ErrorSpec, ScriptedExpert, resample
from aed_tasks.objects.drawer import CABINET_SHAPES, DRAWER_SHAPES, DrawerLayout, build_drawer_unit
from aed_tasks.registration import register_task

CLOSED_TOLERANCE = 0.01  # a drawer out by less than this is fully closed
UNMOVED_TOLERANCE = 0.015  # the distractor may be nudged by less than this
OPEN_AFTER_ERROR = 0.02  # a drawer left out by this much or more is visibly open (error outcomes)
OPENING = (0.09, 0.15)  # how far each drawer starts pulled out
FRONT_X = (0.03, 0.08)  # world x of the cabinets' fronts
CENTRE_Y = (-0.06, 0.06)  # world y of the seam between the two units
SEAM = (0.012, 0.02)  # gap between the two units (the closed fingers span both panels across it)
FINGER_FRONT = 0.010  # the closed fingers' front face, ahead of the TCP along +x
PUSH_BELOW_TOP = (
    0.012  # the TCP pushes this far below the panel's top edge (the hand clears the cabinet)
)
DISTRACTOR_REGION = (-0.3, 0.15, -0.42, 0.42)


@register_task
class CloseDrawerEnv(AEDBaseEnv):
    """
    **Task Description:**
    Two drawer units stand side by side on the table, both drawers pulled out. Fully close
    the drawer the expert closed in the demonstrations (the target, known by its front
    colour and handle) by pushing its front with the closed gripper; the other drawer is
    a task distractor that must not move. Three unrelated objects lie on the table.

    **Randomizations:**
    - per environment: table, floor and wall textures, lighting, cabinet design (plain,
      plinth / legged, crowned), size and material, each drawer's handle design, handle size
      and front colour (target and distractor differ in both)
    - per episode: position of the pair of units (5 x 12 cm), which side the target is on,
      the gap between the units, how far each drawer is out (9 to 15 cm), the positions of
      the environment distractors

    **Success Conditions:**
    - the target drawer is fully closed (out by less than 1 cm) and the distractor drawer
      moved by less than 1.5 cm
    - irrecoverable failure (`fail`): the distractor drawer is fully closed (a top-down
      gripper cannot pull it out again)

    **Stages:** closed (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `not_fully_closed`: the gripper stops pushing partway; the target stays 3.5-6 cm open
      (checked: out by 2 cm or more, the distractor unmoved); the onset is where it stops
    - `closes_distractor`: the distractor drawer is pushed closed instead of the target
      (checked: the distractor closed, the target still out by 2 cm or more)
    - `closes_both`: the gripper pushes at the seam between the units, closing both drawers
      at the same time (checked: both closed)
    """

    task_name = "CloseDrawer"
    catalogue_sizes = {"base": 18, "novel": 18}
    num_stages = 1
    error_kinds = ("not_fully_closed", "closes_distractor", "closes_both")
    recoverable_errors = ("not_fully_closed",)
    num_env_distractors = 3
    max_episode_steps = 200
    eval_horizon = 200

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        target_colour, distractor_colour = pick(rng, object_colours(split), 2)
        target_shape, distractor_shape = pick(rng, DRAWER_SHAPES[split], 2)
        cabinet_size = (
            float(rng.uniform(0.15, 0.18)),
            float(rng.uniform(0.17, 0.2)),
            float(rng.uniform(0.08, 0.1)),
        )

        def drawer(shape: str, colour: tuple[float, ...]) -> ObjectSpec:
            handle = (
                float(rng.uniform(0.06, 0.09)),
                float(rng.uniform(0.018, 0.026)),
            )  # length, reach
            return ObjectSpec(
                shape, handle, MaterialSpec(colour=colour, roughness=float(rng.uniform(0.3, 0.6)))
            )

        return {
            "cabinet": ObjectSpec(
                pick(rng, CABINET_SHAPES[split]),
                cabinet_size,
                sample_material(rng, split, tint=0.3),
            ),
            "target_drawer": drawer(target_shape, target_colour),
            "distractor_drawer": drawer(distractor_shape, distractor_colour),
        }

    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.target_drawer, self.target_layout = build_drawer_unit(
            self.scene, objects["cabinet"], objects["target_drawer"], "target_drawer"
        )
        self.distractor_drawer, self.distractor_layout = build_drawer_unit(
            self.scene, objects["cabinet"], objects["distractor_drawer"], "distractor_drawer"
        )

    def _initialize_task(self, rng: np.random.Generator) -> None:
        width = self.env_spec.objects["cabinet"].size[0]
        front_x = rng.uniform(*FRONT_X)
        seam_y = rng.uniform(*CENTRE_Y)
        offset = width / 2 + rng.uniform(*SEAM) / 2
        side = (
            1.0 if rng.random() < 0.5 else -1.0
        )  # +1: the target stands left (+y) of the distractor
        openings = []
        for unit, layout, sign in (
            (self.target_drawer, self.target_layout, side),
            (self.distractor_drawer, self.distractor_layout, -side),
        ):
            unit.set_pose(Pose.create_from_pq(p=[front_x, seam_y + sign * offset, 0.0]))
            opening = rng.uniform(OPENING[0], min(OPENING[1], layout.travel - 0.005))
            unit.set_qpos(torch.tensor([[opening]], dtype=torch.float32))
            openings.append(opening)
        self.distractor_start = torch.full((self.num_envs,), float(openings[1]), device=self.device)
        self.place_distractors(rng, DISTRACTOR_REGION, self._keep_out(front_x, seam_y, width))
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)

    @staticmethod
    def _keep_out(front_x: float, seam_y: float, width: float) -> list[tuple[float, float, float]]:
        """Circles covering the units, their drawers and the gripper's way in front of them."""
        depth = 0.2
        xs = np.arange(front_x - OPENING[1] - 0.12, front_x + depth + 0.01, 0.06)
        ys = np.arange(seam_y - width - 0.02, seam_y + width + 0.03, 0.06)
        return [(float(x), float(y), 0.05) for x in xs for y in ys]

    # --- evaluation -------------------------------------------------------------------------
    def evaluate(self) -> dict[str, torch.Tensor]:
        target_opening = self.target_drawer.qpos[:, 0]
        distractor_opening = self.distractor_drawer.qpos[:, 0]
        distractor_shift = self.distractor_start - distractor_opening
        closed = target_opening < CLOSED_TOLERANCE
        distractor_unmoved = distractor_shift.abs() < UNMOVED_TOLERANCE
        success = closed & distractor_unmoved
        self.stage_reached = torch.maximum(self.stage_reached, success.to(torch.int32))
        return {
            "success": success,
            # a top-down gripper cannot pull a drawer open again: a closed distractor is final
            "fail": distractor_opening < CLOSED_TOLERANCE,
            "stage": self.stage_reached.clone(),
            "target_opening": target_opening,
            "distractor_shift": distractor_shift,
        }

    def state_entities(self) -> dict:
        return {"target_drawer": self.target_drawer, "distractor_drawer": self.distractor_drawer}

    def _get_obs_extra(self, info: dict) -> dict:
        obs = super()._get_obs_extra(info)
        if self.obs_mode_struct.state:
            obs["target_drawer_qpos"] = self.target_drawer.qpos
            obs["distractor_drawer_qpos"] = self.distractor_drawer.qpos
        return obs

    def error_outcome(self, kind: str) -> str:
        super().error_outcome(kind)
        info = self.evaluate()
        target, distractor = (
            float(info["target_opening"][0]),
            float(self.distractor_drawer.qpos[0, 0]),
        )
        target_closed, distractor_closed = target < CLOSED_TOLERANCE, distractor < CLOSED_TOLERANCE
        shown = {
            "not_fully_closed": target >= OPEN_AFTER_ERROR
            and float(info["distractor_shift"][0].abs()) < UNMOVED_TOLERANCE,
            "closes_distractor": distractor_closed and target >= OPEN_AFTER_ERROR,
            "closes_both": target_closed and distractor_closed,
        }[kind]
        return (
            ""
            if shown
            else f"target out by {target * 100:.1f} cm, distractor out by {distractor * 100:.1f} cm"
        )

    # --- expert -----------------------------------------------------------------------------
    def _front(self, unit, layout: DrawerLayout) -> tuple[np.ndarray, float, float]:
        """A unit's (x, y) origin, its panel's front x now, and that x once closed (world)."""
        origin = unit.pose.p[0].cpu().numpy().astype(np.float64)[:2]
        opening = float(unit.qpos[0, 0])
        closed_x = origin[0] + layout.panel_front_x
        return origin, closed_x - opening, closed_x

    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        kind = error.kind if error else None
        target, target_front, target_closed = self._front(self.target_drawer, self.target_layout)
        other, other_front, other_closed = self._front(
            self.distractor_drawer, self.distractor_layout
        )
        expert.close_gripper(int(expert.rng.integers(5, 9)))  # push with the closed fingertips
        if kind == "closes_distractor":
            expert.mark_error()
            self._push_drawer(expert, other[1], other_front, other_closed, self.distractor_layout)
        elif kind == "closes_both":  # fingers across the seam: both panels are pushed at once
            expert.mark_error()
            seam_y = (target[1] + other[1]) / 2
            layout = self.target_layout
            self._push_drawer(expert, seam_y, min(target_front, other_front), target_closed, layout)
        else:
            stop_short = (
                expert.error_rng.uniform(0.035, 0.06) if kind == "not_fully_closed" else None
            )
            self._push_drawer(
                expert, target[1], target_front, target_closed, self.target_layout, stop_short
            )
        expert.move_by([-expert.rng.uniform(0.04, 0.07), 0.0, expert.rng.uniform(0.06, 0.1)])
        expert.wait(4)

    def _push_drawer(
        self,
        expert: ScriptedExpert,
        y: float,
        front_x: float,
        closed_x: float,
        layout: DrawerLayout,
        stop_short: float | None = None,
    ) -> None:
        """Descend in front of the panel, then push it along +x until closed (or stop short)."""
        z = layout.panel_top_z - PUSH_BELOW_TOP
        start_x = front_x - FINGER_FRONT - layout.handle_reach - expert.rng.uniform(0.015, 0.03)
        hover = np.array(
            [start_x - expert.rng.uniform(0.0, 0.02), y, z + expert.rng.uniform(0.06, 0.12)]
        )
        expert.move_to(hover + np.array([0.0, expert.rng.uniform(-0.01, 0.01), 0.0]))
        expert.move_to(np.array([start_x, y, z]), speed=expert.speed * 0.7)
        end = np.array([closed_x - FINGER_FRONT + 0.008, y, z])
        stop_x = None if stop_short is None else closed_x - stop_short - FINGER_FRONT
        for waypoint in resample(
            np.array([expert.tcp, end]), expert.speed * expert.rng.uniform(0.45, 0.65)
        ):
            if stop_x is not None and expert.tcp[0] >= stop_x:
                expert.mark_error()  # the gripper stops pushing here
                return
            expert.step(waypoint - expert.tcp)
        for _ in range(
            12
        ):  # lean on the panel until the tip is at the end (the joint limit stops it)
            if stop_x is not None and expert.tcp[0] >= stop_x:
                expert.mark_error()
                return
            expert.step(end - expert.tcp)

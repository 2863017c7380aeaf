"""Organize Table: put the item in front of the target bookshelf and push it fully under."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.assets import texture_names
from aed_tasks.base_env import AEDBaseEnv
from aed_tasks.catalogue import MaterialSpec, ObjectSpec, object_colours, pick
from aed_tasks.expert import OPEN, ErrorSpec, ScriptedExpert, resample
from aed_tasks.objects.shelf import (
    ITEM_SHAPES,
    SHELF_SHAPES,
    build_item,
    build_shelf,
    item_corners,
    sample_shelf_size,
    shelf_opening,
)
from aed_tasks.registration import register_task
from aed_tasks.scene import rotation_z

ITEM_REGION = (-0.30, -0.20, -0.08, 0.08)  # x0, x1, y0, y1 of the item's start on the table top
ITEM_YAW = 0.25  # the item's start yaw, within +-ITEM_YAW rad of the x axis
SHELF_FRONT_X = (-0.04, 0.03)  # where the shelves' mouths stand (x of the opening plane)
SHELF_SIDE_Y = (0.19, 0.24)  # |y| of the shelves' centres: one on each side of the table
LANE_HALF_WIDTH = 0.04  # |y| offset from the shelf's centre line counted as "in front of it"
LANE_DEPTH = 0.12  # how far before the mouth the item still counts as "in front of it"
FINGER_HALF = 0.011  # half thickness of a Panda finger along x: its front face leads the TCP
WRIST_LEAD = 0.045  # how far the wrist (link 6) leads the TCP along +x: it must not hit the board
PUSH_Z = 0.018  # TCP height while pushing: fingertips 9 mm over the table, hand bottom at 5.5 cm
RESTING = 0.01  # the item lies on the table: its bounding box at most this far above it (m)
OFF_TABLE = 0.005  # bottom this far above the table: lifted (or held)


@register_task
class OrganizeTableEnv(AEDBaseEnv):
    """
    **Task Description:**
    Pick up the item (a block, book, canister or loaf), place it on the table in front of
    the bookshelf that the expert used in the demonstrations, and push it fully under that
    shelf. A second bookshelf of another colour stands on the other side: a task distractor.

    **Randomizations:**
    - per environment: table, floor and wall textures, lighting, the item's shape, size and
      colour, both shelves' designs, sizes (width, depth, clearance), colours and textures
      (target and distractor differ in colour)
    - per episode: item position in a 10 x 20 cm region and its yaw (+-0.25 rad); which
      side the target shelf stands on, and both shelves' positions (7 cm in x, 5 cm in y)

    **Success Conditions:**
    - every corner of the item's bounding box lies in the free space under the target
      shelf's lowest board (between its supports, behind its mouth, within its depth), the
      item rests on the table there (every corner at most `RESTING` = 1 cm above the table
      and below the item's height + 1 cm: lying flat, not tilted onto something, not held
      up) and the gripper does not hold it. The clearance under the board is 33.5-36 cm:
      the wrist passes under it while the fingertips push the item the last centimetres,
      so "under the board" is a height check only with "resting on the table".

    **Stages:** picked (lifted while grasped), placed in front of the target shelf
    (released on the table in its lane), pushed under (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `no_grasp`: the fingers close 2.5-3.5 cm beyond one end of the item; it is never
      picked up (checked: never lifted `OFF_TABLE` = 5 mm, lying on the table)
    - `drop_while_moving`: the gripper opens 25-55% of the way to the shelf; the item falls
      short (checked: lifted 2 cm, then lying on the table neither in the lane nor under)
    After either, the script goes on blindly: it places nothing and pushes where the item
    would lie.
    - `not_fully_under`: the push stops with the item's rear 1.2 cm to half its length
      before the mouth (checked: part of it under the board, part out of the mouth); the
      onset is where the push stops, the clean push having been followed until then
    """

    task_name = "OrganizeTable"
    catalogue_sizes = {"base": 49, "novel": 25}
    num_stages = 3
    error_kinds = ("no_grasp", "drop_while_moving", "not_fully_under")
    recoverable_errors = ("no_grasp", "drop_while_moving", "not_fully_under")
    max_episode_steps = 400
    eval_horizon = 390

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        item_colour, target_colour, distractor_colour = pick(rng, object_colours(split), 3)
        return {
            "item": ObjectSpec(
                (shape := pick(rng, ITEM_SHAPES[split])),
                _item_size(rng, shape),
                MaterialSpec(colour=item_colour, roughness=float(rng.uniform(0.3, 0.7))),
            ),
            "target_shelf": _shelf_spec(rng, split, target_colour),
            "distractor_shelf": _shelf_spec(rng, split, distractor_colour),
        }

    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.item = build_item(self.scene, objects["item"], "item")
        self.target_shelf = build_shelf(self.scene, objects["target_shelf"], "target_shelf")
        self.distractor_shelf = build_shelf(
            self.scene, objects["distractor_shelf"], "distractor_shelf"
        )

    def _initialize_task(self, rng: np.random.Generator) -> None:
        side = 1.0 if rng.random() < 0.5 else -1.0
        for shelf, key, sign in (
            (self.target_shelf, "target_shelf", side),
            (self.distractor_shelf, "distractor_shelf", -side),
        ):
            half_depth = self.env_spec.objects[key].size[1] / 2
            x = rng.uniform(*SHELF_FRONT_X) + half_depth
            shelf.set_pose(Pose.create_from_pq(p=[x, sign * rng.uniform(*SHELF_SIDE_Y), 0.0]))
        x0, x1, y0, y1 = ITEM_REGION
        item_xy = [rng.uniform(x0, x1), rng.uniform(y0, y1)]
        self.item.set_pose(
            Pose.create_from_pq(
                p=[*item_xy, 0.0005], q=rotation_z(rng.uniform(-ITEM_YAW, ITEM_YAW))
            )
        )
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)
        self.highest = torch.zeros(
            self.num_envs, device=self.device
        )  # the item's highest bottom so far

    # --- evaluation -------------------------------------------------------------------------
    def _corners_under(self) -> torch.Tensor:
        """(n, 8): which corners of the item lie in the free space under the target shelf."""
        half_width, half_depth, clearance = shelf_opening(self.env_spec.objects["target_shelf"])
        rel = (
            item_corners(self.item, self.env_spec.objects["item"])
            - self.target_shelf.pose.p[:, None, :]
        )
        return (
            (rel[..., 0].abs() <= half_depth)
            & (rel[..., 1].abs() <= half_width)
            & (rel[..., 2] <= clearance)
        )

    def _fully_under(self) -> torch.Tensor:
        """Every corner of the item under the target shelf, the item lying on the table."""
        return self._corners_under().all(dim=1) & self._resting()

    def _resting(self) -> torch.Tensor:
        """The item lies flat on the table: its bounding box no higher than it is tall."""
        height = self.env_spec.objects["item"].size[2]
        z = item_corners(self.item, self.env_spec.objects["item"])[..., 2]
        return (z.min(dim=1).values <= RESTING) & (z.max(dim=1).values <= height + RESTING)

    def _in_front_of_target(self) -> torch.Tensor:
        """The item rests on the table in the target shelf's lane, before or in its mouth."""
        half_depth = self.env_spec.objects["target_shelf"].size[1] / 2
        rel = self.item.pose.p - self.target_shelf.pose.p
        ahead = rel[:, 0] + half_depth  # item centre relative to the mouth plane
        in_lane = (
            (rel[:, 1].abs() < LANE_HALF_WIDTH) & (ahead > -LANE_DEPTH) & (ahead < 2 * half_depth)
        )
        return in_lane & (self.item.pose.p[:, 2] < 0.01)

    def evaluate(self) -> dict[str, torch.Tensor]:
        grasped = self.agent.is_grasping(self.item)
        picked = grasped & (self.item.pose.p[:, 2] > 0.02)
        placed = self._in_front_of_target() & ~grasped
        under = self._fully_under() & ~grasped
        self.highest = torch.maximum(self.highest, self.item.pose.p[:, 2])
        stage = torch.where(under, 3, torch.where(placed, 2, torch.where(picked, 1, 0))).to(
            torch.int32
        )
        self.stage_reached = torch.maximum(self.stage_reached, stage)
        return {
            "success": under,
            "fail": self.objects_off_table(self.item),
            "stage": self.stage_reached.clone(),
            "is_grasped": grasped,
        }

    def state_entities(self) -> dict:
        return {
            "item": self.item,
            "target_shelf": self.target_shelf,
            "distractor_shelf": self.distractor_shelf,
        }

    def error_outcome(self, kind: str) -> str:
        problem = super().error_outcome(kind)
        if problem:
            return problem
        if bool(self.agent.is_grasping(self.item)[0]):
            return "the gripper still holds the item"
        if not bool(self._resting()[0]):
            return "the item does not lie on the table"
        highest, under = float(self.highest[0]), self._corners_under()[0]
        if kind == "no_grasp":
            return "" if highest < OFF_TABLE else f"the item was lifted {highest * 100:.1f} cm"
        if kind == "drop_while_moving":
            if highest < 0.02:
                return f"the item was never carried (lifted {highest * 100:.1f} cm)"
            if bool(self._in_front_of_target()[0]) or bool(under.any()):
                return "the item reached the target shelf"
            return ""
        if not bool(under.any()):
            return "no part of the item is under the shelf"
        return "" if not bool(under.all()) else "the item is fully under the shelf"

    # --- expert -----------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        kind = error.kind if error else None
        if kind is None and bool(self._in_front_of_target()[0]):  # a retry: it only needs a push
            self._push_under(expert, None)
            return
        self._pick(expert, kind)
        place = self._carry_and_place(expert, kind)
        # after a miss or a drop the script goes on blindly: it pushes where the item should be
        self._push_under(expert, kind, place if kind in ("no_grasp", "drop_while_moving") else None)

    def _item_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Bottom centre and bounding-box corners (8, 3) of the item, as read now."""
        corners = (
            item_corners(self.item, self.env_spec.objects["item"])[0]
            .cpu()
            .numpy()
            .astype(np.float64)
        )
        return self.item.pose.p[0].cpu().numpy().astype(np.float64), corners

    def _mouth(self) -> tuple[float, float]:
        """x of the target shelf's mouth and y of its centre line."""
        shelf = self.target_shelf.pose.p[0].cpu().numpy()
        return float(shelf[0] - shelf_opening(self.env_spec.objects["target_shelf"])[1]), float(
            shelf[1]
        )

    def _pick(self, expert: ScriptedExpert, kind: str | None) -> None:
        position, corners = self._item_state()
        length = self.env_spec.objects["item"].size[0]
        grasp = np.array([position[0], position[1], max(corners[:, 2].mean(), 0.016)])
        hover = grasp + [0.0, 0.0, expert.rng.uniform(0.08, 0.13)]
        expert.gripper = OPEN  # (a retry may start with closed fingers)
        expert.move_to(hover + [0.0, 0.0, 0.04] + expert.jitter(0.03))
        expert.move_to(hover + expert.jitter(0.003))  # straight over it: the descent stays vertical
        if kind == "no_grasp":  # close the fingers just past one end of the item
            expert.mark_error()
            grasp[0] += np.sign(expert.error_rng.uniform(-1, 1)) * (
                length / 2 + expert.error_rng.uniform(0.025, 0.035)
            )
        expert.move_to(grasp, speed=expert.speed * 0.6)
        expert.close_gripper()
        expert.move_by([0.0, 0.0, expert.rng.uniform(0.06, 0.10)], speed=expert.speed * 0.7)

    def _carry_and_place(self, expert: ScriptedExpert, kind: str | None) -> np.ndarray:
        """Carry the item to the target's lane and set it down; returns the TCP's place point."""
        length, _, height = self.env_spec.objects["item"].size
        mouth_x, centre_y = self._mouth()
        place = np.array(
            [
                mouth_x - expert.rng.uniform(0.035, 0.06) - length / 2,
                centre_y + expert.rng.uniform(-0.008, 0.008),
                max(height * 0.5, 0.016) + 0.004,
            ]
        )
        above = np.array([place[0], place[1], expert.tcp[2]])
        drop_at = expert.error_rng.uniform(0.25, 0.55) if kind == "drop_while_moving" else None
        _carry(expert, above, drop_at)
        expert.move_to(place, speed=expert.speed * 0.6)
        expert.open_gripper()
        return place

    def _push_under(
        self, expert: ScriptedExpert, kind: str | None, blind_at: np.ndarray | None = None
    ) -> None:
        """Get behind the item, close the fingers and push it along +x under the shelf.

        With `blind_at` (a place point of `_carry_and_place`) the push goes where the item
        would lie had it been placed there, not where it is.
        """
        length, _, height = self.env_spec.objects["item"].size
        mouth_x, _ = self._mouth()
        if blind_at is None:
            position, corners = self._item_state()
            y, rear, top = position[1], corners[:, 0].min(), corners[:, 2].max()
        else:
            y, rear, top = blind_at[1], blind_at[0] - length / 2, height
        start_x = min(
            rear - FINGER_HALF - expert.rng.uniform(0.012, 0.02), mouth_x - WRIST_LEAD - 0.015
        )
        if expert.tcp[2] < top and abs(expert.tcp[1] - y) < 0.01 and expert.tcp[0] > rear:
            # just released it: slide back out between the item and the open fingers
            expert.move_to(np.array([start_x, y, expert.tcp[2]]), speed=expert.speed * 0.6)
        else:
            expert.move_to(np.array([start_x, y, top + 0.04]) + expert.jitter(0.005))
        expert.close_gripper(6)
        expert.move_to(np.array([start_x, y, PUSH_Z]), speed=expert.speed * 0.6)
        end_x = mouth_x + expert.rng.uniform(0.012, 0.022) - FINGER_HALF
        stop_before = None
        if (
            kind == "not_fully_under"
        ):  # push as the clean expert does, stop with the item sticking out
            stop_x = mouth_x - expert.error_rng.uniform(0.012, 0.5 * length) - FINGER_HALF

            def stop_before(waypoint: np.ndarray) -> bool:
                return bool(waypoint[0] > stop_x)

        if expert.move_to(
            np.array([end_x, y, PUSH_Z]),
            speed=expert.rng.uniform(0.006, 0.009),
            stop_before=stop_before,
        ):
            expert.mark_error()  # the push stops here: the clean expert would go on
        expert.move_to(np.array([start_x - 0.03, y, PUSH_Z + 0.01]), speed=expert.speed * 0.8)
        expert.move_by([0.0, 0.0, expert.rng.uniform(0.06, 0.1)])
        expert.wait(4)


def _carry(
    expert: ScriptedExpert, target: np.ndarray, drop_at: float | None, tol: float = 0.006
) -> None:
    """`expert.move_to(target)`, but opening the gripper at fraction `drop_at` of the way."""
    waypoints = resample(expert.plan(target), expert.speed)
    drop_step = None if drop_at is None else int(len(waypoints) * drop_at)
    for i, waypoint in enumerate(waypoints):
        if i == drop_step:
            expert.mark_error()
            expert.gripper = OPEN
        expert.step(waypoint - expert.tcp)
    for _ in range(12):
        if np.linalg.norm(target - expert.tcp) < tol:
            break
        expert.step(target - expert.tcp)


def _item_size(rng: np.random.Generator, shape: str) -> tuple[float, float, float]:
    """(length x, width y, height): narrow enough along y for the open Panda fingers."""
    if shape == "item_canister":
        diameter = float(rng.uniform(0.036, 0.042))
        return float(rng.uniform(0.06, 0.085)), diameter, diameter
    if shape == "item_loaf":  # taller than wide: the round roof sits on a box of at least 4 mm
        width = float(rng.uniform(0.04, 0.046))
        return float(rng.uniform(0.055, 0.085)), width, float(rng.uniform(width + 0.004, 0.052))
    return (
        float(rng.uniform(0.055, 0.085)),
        float(rng.uniform(0.04, 0.052)),
        float(rng.uniform(0.034, 0.042)),
    )


def _shelf_spec(
    rng: np.random.Generator, split: str, colour: tuple[float, float, float, float]
) -> ObjectSpec:
    size = sample_shelf_size(rng)
    material = MaterialSpec(
        colour=colour,
        texture=pick(rng, texture_names(split)),
        roughness=float(rng.uniform(0.5, 0.9)),
    )
    return ObjectSpec(pick(rng, SHELF_SHAPES[split]), size, material)

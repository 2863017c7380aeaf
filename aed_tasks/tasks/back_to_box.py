"""Back to Box: put the magic cube (or die) into the storage box, push the box under the shelf."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.base_env import AEDBaseEnv
from aed_tasks.catalogue import MaterialSpec, ObjectSpec, object_colours, pick, sample_material
from aed_tasks.expert import ErrorSpec, ScriptedExpert
from aed_tasks.objects.storage_box import (
    BOX_SHAPES,
    CUBE_SHAPES,
    SHELF_RECESS,
    SHELF_SHAPES,
    BoxGeometry,
    ShelfGeometry,
    build_bookshelf,
    build_storage_box,
    build_toy_cube,
)
from aed_tasks.registration import register_task
from aed_tasks.scene import rotation_z

# Panda hand seen from its TCP (top-down gripper): fingers reach 1.1 cm ahead (x) and 1 cm
# below; the hand body starts 3.7 cm above the TCP.
FINGER_FRONT = 0.011
HAND_ABOVE_TCP = 0.037
# the hand leads the TCP by 3.4 cm: it stops the push this far before the board (box rear
# 2.3 cm before it), so the box may stick out of the board by at most MAX_OUT_OF_BOARD
HAND_LEAD = 0.034
MAX_OUT_OF_BOARD = 0.03
CLEARLY_OUT = 0.05  # `box_not_under` leaves the box's rear at least this far before the board
DISTRACTOR_REGION = (-0.35, 0.3, -0.45, 0.45)


@register_task
class BackToBoxEnv(AEDBaseEnv):
    """
    **Task Description:**
    Pick up the magic cube (or die), place it into the open storage box, then push the box
    (closed gripper, from the robot's side, along +x) until it is fully under the low
    bookshelf in front of the robot. Three unrelated objects clutter the table.

    **Randomizations:**
    - per environment: table, floor and wall textures, lighting, toy kind (magic cube or
      die), its size and colours, storage box design, size and material, bookshelf design,
      size and material, the three distractors
    - per episode: bookshelf position (front edge x in [0.03, 0.07], y in [-0.1, 0.1]), box
      position in front of it (a few cm sideways, slightly turned), toy position beside the
      box (15-22 cm to either side) and yaw, distractor positions

    **Success Conditions:**
    - the toy rests inside the storage box (released: its centre within the inner walls,
      above the floor, below the rim), and
    - the box is under the shelf's board: its footprint lies between the shelf's sides and
      before its back, and no corner stands more than `MAX_OUT_OF_BOARD` = 3 cm in front of
      the board (at least 70% of the box's 9-11 cm depth under the board). The board is
      measured, not the side panels' front edges 5 cm ahead of it; 3 cm, because the
      top-down hand (3.4 cm ahead of the TCP) must stay in front of the board, so the push
      leaves the box's rear about 2.3 cm before it.

    **Stages:** picked (lifted while grasped), in box (released inside it), box under the
    shelf (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `no_grasp`: the fingers close 1.2-2 cm in front of or behind the toy; it is never
      picked up (checked: never lifted 1 cm, not in the box)
    - `miss_box`: the toy is carried towards the box but set down on the table beside it
      (checked: lifted, then resting on the table out of the box); the onset is where the
      carry stops short, the clean carry having been followed until then
    - `box_not_under`: the push stops with the box's rear 8-14 cm before the board (checked:
      toy in the box, the box's rear at least `CLEARLY_OUT` = 5 cm before the board); the
      onset is where the push stops, the clean push having been followed until then
    """

    task_name = "BackToBox"
    catalogue_sizes = {"base": 60, "novel": 18}
    num_stages = 3
    error_kinds = ("no_grasp", "miss_box", "box_not_under")
    recoverable_errors = ("no_grasp", "miss_box", "box_not_under")
    num_env_distractors = 3
    max_episode_steps = 400
    eval_horizon = 400

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        toy_colour = pick(rng, object_colours(split))
        box_colour = pick(rng, [c for c in object_colours(split) if c != toy_colour])
        box_material = sample_material(rng, split)
        return {
            "toy": ObjectSpec(
                pick(rng, CUBE_SHAPES[split]),
                (float(rng.uniform(0.036, 0.045)),),
                MaterialSpec(colour=toy_colour, roughness=float(rng.uniform(0.3, 0.6))),
            ),
            "box": ObjectSpec(
                pick(rng, BOX_SHAPES[split]),
                tuple(
                    float(v)
                    for v in (
                        rng.uniform(0.09, 0.11),
                        rng.uniform(0.11, 0.14),
                        rng.uniform(0.044, 0.052),
                        rng.uniform(0.005, 0.007),
                    )
                ),
                MaterialSpec(
                    colour=box_colour,
                    texture=box_material.texture,
                    roughness=box_material.roughness,
                ),
            ),
            "shelf": ObjectSpec(
                pick(rng, SHELF_SHAPES[split]),
                tuple(
                    float(v)
                    for v in (
                        rng.uniform(0.2, 0.24),
                        rng.uniform(0.3, 0.34),
                        rng.uniform(0.075, 0.09),
                        rng.uniform(0.19, 0.22),
                    )
                ),
                sample_material(rng, split, tint=0.35),
            ),
        }

    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.toy = build_toy_cube(self.scene, objects["toy"], "toy")
        self.box = build_storage_box(self.scene, objects["box"], "storage_box")
        self.shelf = build_bookshelf(self.scene, objects["shelf"], "bookshelf")
        self.box_geometry = BoxGeometry.of(objects["box"])
        self.shelf_geometry = ShelfGeometry.of(objects["shelf"])
        self.toy_edge = objects["toy"].size[0]

    def _initialize_task(self, rng: np.random.Generator) -> None:
        box, shelf = self.box_geometry, self.shelf_geometry
        front_x, shelf_y = rng.uniform(0.03, 0.07), rng.uniform(-0.1, 0.1)
        self.shelf.set_pose(Pose.create_from_pq(p=[front_x, shelf_y, 0.0]))
        box_y = shelf_y + rng.uniform(-0.02, 0.02)
        box_x = rng.uniform(-0.2, -0.14) + box.depth / 2
        self.box.set_pose(
            Pose.create_from_pq(p=[box_x, box_y, 0.0005], q=rotation_z(rng.uniform(-0.06, 0.06)))
        )
        side = 1.0 if rng.random() < 0.5 else -1.0
        toy_y = box_y + side * rng.uniform(0.15, 0.22)
        if abs(toy_y) > 0.32:
            toy_y = box_y - side * rng.uniform(0.15, 0.22)
        toy_x = rng.uniform(-0.28, -0.1)
        yaw = rng.uniform(-0.35, 0.35)
        self.toy.set_pose(
            Pose.create_from_pq(p=[toy_x, toy_y, self.toy_edge / 2 + 0.0005], q=rotation_z(yaw))
        )
        keep_out = [(toy_x, toy_y, 0.05)]
        keep_out += [
            (x, box_y, box.width / 2 + 0.03)
            for x in np.linspace(box_x - box.depth / 2 - 0.06, front_x, 6)
        ]
        keep_out += [
            (x, shelf_y + dy, 0.1)
            for x in np.linspace(front_x - 0.02, front_x + shelf.depth, 4)
            for dy in (-0.1, 0.0, 0.1)
        ]
        keep_out += [(x, y, 0.05) for x, y in np.linspace([toy_x, toy_y], [box_x, box_y], 5)]
        self.place_distractors(rng, DISTRACTOR_REGION, keep_out)
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)
        self.highest = torch.zeros(
            self.num_envs, device=self.device
        )  # the toy's highest centre so far

    # --- evaluation -------------------------------------------------------------------------
    def toy_in_box(self) -> torch.Tensor:
        """The toy's centre lies inside the box's walls, below their top."""
        local = (self.box.pose.inv() * self.toy.pose).p
        half_x, half_y = self.box_geometry.inner_half
        inside = (local[:, 0].abs() < half_x) & (local[:, 1].abs() < half_y)
        return (
            inside
            & (local[:, 2] > self.box_geometry.floor)
            & (local[:, 2] < self.box_geometry.height)
        )

    def _box_corners_in_shelf(self) -> torch.Tensor:
        """(n, 4, 3): the corners of the box's footprint in the shelf's frame."""
        g = self.box_geometry
        corners = torch.tensor(
            [[sx * g.depth / 2, sy * g.width / 2, 0.0, 1.0] for sx in (-1, 1) for sy in (-1, 1)],
            device=self.device,
        )
        to_shelf = (
            self.shelf.pose.inv().to_transformation_matrix()
            @ self.box.pose.to_transformation_matrix()
        )
        return torch.einsum("nij,kj->nki", to_shelf, corners)[..., :3]

    def box_out_of_board(self) -> torch.Tensor:
        """How far (m) the box's hindmost corner stands in front of the board (<= 0: under it)."""
        return SHELF_RECESS - self._box_corners_in_shelf()[..., 0].min(dim=1).values

    def box_under_shelf(self) -> torch.Tensor:
        """The box between the shelf's sides, before its back, at most 3 cm out of the board."""
        local, s = self._box_corners_in_shelf(), self.shelf_geometry
        within_x = (local[..., 0] >= SHELF_RECESS - MAX_OUT_OF_BOARD) & (local[..., 0] <= s.depth)
        within_y = local[..., 1].abs() <= s.inner_width / 2
        return (within_x & within_y).all(dim=1)

    def evaluate(self) -> dict[str, torch.Tensor]:
        grasped = self.agent.is_grasping(self.toy)
        lifted = self.toy.pose.p[:, 2] > self.toy_edge / 2 + 0.02
        in_box = self.toy_in_box() & ~grasped
        under = self.box_under_shelf()
        success = in_box & under
        self.highest = torch.maximum(self.highest, self.toy.pose.p[:, 2])
        stage = torch.where(
            success, 3, torch.where(in_box, 2, torch.where(grasped & lifted, 1, 0))
        ).to(torch.int32)
        self.stage_reached = torch.maximum(self.stage_reached, stage)
        return {
            "success": success,
            "fail": self.objects_off_table(self.toy, self.box),
            "stage": self.stage_reached.clone(),
            "is_grasped": grasped,
            "toy_in_box": in_box,
            "box_under_shelf": under,
        }

    def state_entities(self) -> dict:
        return {"toy": self.toy, "storage_box": self.box, "bookshelf": self.shelf}

    def error_outcome(self, kind: str) -> str:
        problem = super().error_outcome(kind)
        if problem:
            return problem
        if bool(self.agent.is_grasping(self.toy)[0]):
            return "the gripper still holds the toy"
        lifted = float(self.highest[0]) - self.toy_edge / 2
        in_box = bool(self.toy_in_box()[0])
        if kind == "no_grasp":
            if lifted > 0.01:
                return f"the toy was lifted {lifted * 100:.1f} cm"
            return "the toy is in the box" if in_box else ""
        if kind == "miss_box":
            if lifted < 0.02:
                return f"the toy was never carried (lifted {lifted * 100:.1f} cm)"
            on_table = float(self.toy.pose.p[0, 2]) < self.toy_edge / 2 + 0.005
            return "" if not in_box and on_table else "the toy is in the box or not on the table"
        if not in_box:
            return "the toy is not in the box"
        out = float(self.box_out_of_board()[0])
        return (
            ""
            if out >= CLEARLY_OUT
            else f"the box's rear is only {out * 100:.1f} cm before the board"
        )

    # --- expert -----------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        """Pick & place (skipped when the toy is already in the box), then the push.

        It reads the poses where it starts, so after a recoverable error it can simply be
        run again from the state the error left behind.
        """
        kind = error.kind if error else None
        if not bool(self.toy_in_box()[0]) and not self._put_toy_in_box(expert, kind):
            return
        self._push_box_under(expert, kind)

    def _put_toy_in_box(self, expert: ScriptedExpert, kind: str | None) -> bool:
        """Grasp the toy and release it above the box; False when an error ended the attempt."""
        edge = self.toy_edge
        toy = self.toy.pose.p[0].cpu().numpy().astype(np.float64)
        grasp = np.array([toy[0], toy[1], max(toy[2], 0.017)])
        expert.move_to(grasp + [0.0, 0.0, expert.rng.uniform(0.08, 0.13)] + expert.jitter(0.02))
        if kind == "no_grasp":  # the fingers come down in front of or behind the toy
            expert.mark_error()
            side = np.sign(expert.error_rng.uniform(-1, 1))
            offset = side * (edge / 2 + FINGER_FRONT + expert.error_rng.uniform(0.012, 0.02))
            grasp = grasp + [offset, 0.0, 0.0]
        expert.move_to(grasp, speed=expert.speed * 0.6)
        expert.close_gripper()
        expert.move_by([0.0, 0.0, expert.rng.uniform(0.12, 0.17)], speed=expert.speed * 0.7)

        g = self.box_geometry
        box = self.box.pose.p[0].cpu().numpy().astype(np.float64)
        release = np.array([box[0], box[1], g.height + edge / 2 + expert.rng.uniform(0.012, 0.02)])
        over_box = np.array([release[0], release[1], expert.tcp[2]]) + expert.jitter(0.01)
        stop_before = None
        if kind == "miss_box":  # carry as the clean expert does, stop short beside the box
            side = np.sign(expert.tcp[1] - box[1]) or 1.0
            miss_y = box[1] + side * (
                g.width / 2 + edge / 2 + expert.error_rng.uniform(0.065, 0.085)
            )  # room for the fingers

            def stop_before(waypoint: np.ndarray) -> bool:
                return bool(side * (waypoint[1] - miss_y) <= 0)

        if expert.move_to(over_box, stop_before=stop_before):
            expert.mark_error()  # the carry stops here: the clean expert would go on to the box
            release = np.array([expert.tcp[0], miss_y, edge / 2 + 0.012])
        expert.move_to(release, speed=expert.speed * 0.6)
        expert.open_gripper()
        expert.move_by([0.0, 0.0, expert.rng.uniform(0.05, 0.08)])
        if kind in ("no_grasp", "miss_box"):
            expert.wait(4)  # the same rest as after a push
            return False
        return True

    def _push_box_under(self, expert: ScriptedExpert, kind: str | None) -> None:
        """Fingers closed behind the box's back wall, push along +x until it is under the shelf.

        The push is closed-loop: each step reads the box's pose, and the push goes on until
        the box's hindmost corner (the box may turn a little on the way) is past the goal.
        """
        g = self.box_geometry
        rear = self._box_rear()
        front_x = float(self.shelf.pose.p[0, 0])
        push_z = max(0.02, g.height + 0.006 - HAND_ABOVE_TCP) + expert.rng.uniform(0.0, 0.004)
        start_x = rear[0] - FINGER_FRONT - expert.rng.uniform(0.02, 0.035)
        expert.move_to(np.array([start_x, rear[1], max(expert.tcp[2], g.height + 0.05)]))
        expert.close_gripper(6)
        expert.move_to(np.array([start_x, rear[1], push_z]), speed=expert.speed * 0.7)
        # the clean push goes on until the hand is as close to the board as it may come
        stop_at = (
            front_x - expert.error_rng.uniform(0.03, 0.09) if kind == "box_not_under" else None
        )
        self._push_until(
            expert, front_x + SHELF_RECESS, push_z, speed=expert.speed * 0.6, stop_at=stop_at
        )
        if (
            kind == "box_not_under"
        ):  # stops short of the shelf and backs away (marked where it stops)
            expert.mark_error()
        expert.move_by([-expert.rng.uniform(0.04, 0.07), 0.0, 0.0])
        expert.move_by([0.0, 0.0, expert.rng.uniform(0.08, 0.12)])
        expert.wait(4)

    def _box_rear(self) -> np.ndarray:
        """World position of the middle of the box's back (robot-side) wall, at its bottom."""
        rear = self.box.pose * Pose.create_from_pq(p=[-self.box_geometry.depth / 2, 0.0, 0.0])
        return rear.p[0].cpu().numpy().astype(np.float64)

    def _push_until(
        self,
        expert: ScriptedExpert,
        goal: float,
        push_z: float,
        speed: float,
        stop_at: float | None = None,
    ) -> None:
        """Push along +x until the box's hindmost corner passes x = `goal`.

        With `stop_at` (an error's shortened push) it stops, marking the onset, before the
        first step whose box has its hindmost corner past `stop_at` already.
        """
        g = self.box_geometry
        # the hand must stay in front of the recessed board: it reaches 3.4 cm past the TCP
        tcp_limit = float(self.shelf.pose.p[0, 0]) + SHELF_RECESS - HAND_LEAD
        stalled = 0
        line_y = expert.tcp[1]
        for _ in range(200):
            pose = self.box.pose
            q = pose.q[0].cpu().numpy()
            yaw = 2 * np.arctan2(q[3], q[0])
            centre = pose.p[0].cpu().numpy()
            hindmost = centre[0] - g.depth / 2 * abs(np.cos(yaw)) - g.width / 2 * abs(np.sin(yaw))
            remaining = goal - hindmost
            tcp = expert.tcp
            if remaining <= 0 or tcp[0] >= tcp_limit or stalled > 15:
                return
            if stop_at is not None and hindmost >= stop_at:
                expert.mark_error()  # the clean push goes on from here
                return
            advance = min(speed, remaining + 0.002, tcp_limit - tcp[0])
            delta = np.array(
                [advance, np.clip(line_y - tcp[1], -speed / 2, speed / 2), push_z - tcp[2]]
            )
            expert.step(delta)
            stalled = stalled + 1 if np.linalg.norm(expert.tcp - tcp) < 5e-4 else 0

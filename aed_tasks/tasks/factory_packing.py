"""Factory Packing: pack the product into the box that a conveyor brings, send the box on."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.assets import texture_names
from aed_tasks.base_env import AEDBaseEnv, sample_free_xy
from aed_tasks.catalogue import (
    EnvironmentSpec,
    MaterialSpec,
    ObjectSpec,
    catalogue_rng,
    object_colours,
    pick,
)
from aed_tasks.expert import OPEN, ErrorSpec, ScriptedExpert
from aed_tasks.objects.conveyor import (
    BELT_TOP,
    WALL_THICKNESS,
    box_half_reach,
    build_conveyor,
    build_packing_box,
    build_pillars,
    build_product,
)
from aed_tasks.registration import register_task
from aed_tasks.scene import TABLE_HEIGHT, rotation_z

BOX_SHAPES = {"base": ("box_plain", "box_flanged"), "novel": ("box_handled", "box_cornered")}
PRODUCT_SHAPES = {
    "base": ("product_carton", "product_can"),
    "novel": ("product_tub", "product_jar"),
}
CONVEYOR_SHAPES = {"base": ("conveyor_railed",), "novel": ("conveyor_rollered",)}
# Factory looks, drawn from each split's own texture pool (concrete, epoxy, steel, plate).
FACTORY_TEXTURES = {
    "base": {
        "floor": ("noise_1", "checker_1", "noise_2", "noise_5"),
        "wall": ("noise_1", "stripes_1", "checker_2", "noise_3"),
        "table": ("noise_1", "wood_1", "stripes_1"),
        "belt": ("noise_5", "stripes_5", "stripes_2"),  # green / blue belts
    },
    "novel": {
        "floor": ("weave_1", "dots_1", "tiles_1", "marble_1"),
        "wall": ("tiles_0", "marble_0", "tiles_1", "dots_0"),
        "table": ("weave_0", "marble_0", "tiles_0", "dots_0"),
        "belt": ("weave_1", "dots_1", "tiles_1"),  # charcoal belts
    },
}
# Base colours under those textures, by split: grey halls (base), warm-tinted halls (novel).
FACTORY_TINTS = {
    "base": {"floor": (1.0, 1.0, 1.0), "wall": (0.85, 0.86, 0.82), "table": (0.8, 0.82, 0.85)},
    "novel": {"floor": (1.0, 0.9, 0.8), "wall": (0.95, 0.85, 0.9), "table": (0.9, 0.95, 0.8)},
}

# Layout on the operating table (top at z = 0; the robot stands at x = -0.615).
BELT_WIDTH = 0.16
IN_BELT_Y, IN_BELT_X = 0.24, (-0.075, 0.47)  # incoming belt runs towards -x, end stop at x0
OUT_BELT_Y, OUT_BELT_X = -0.24, (-0.16, 0.43)  # outgoing belt runs towards +x, end stop at x1
BOX_START_X = (0.34, 0.41)  # box centre on the incoming belt at reset: out of the robot's reach
DESTINATION_X = 0.30  # the box centre beyond this, on the outgoing belt: delivered
PRODUCT_REGION = (-0.25, -0.12, -0.07, 0.07)  # x0, x1, y0, y1
BELT_SPEED = (0.10, 0.14)  # m/s, per episode and belt
PILLARS = [(-1.25, -0.95), (-1.25, 0.95)]
MISS_OFFSET = 0.15  # `miss_belt` sets the box down this far (y) short of or past the belt's centre


def factory_background(rng: np.random.Generator, split: str) -> dict[str, MaterialSpec]:
    """Floor, wall and table of a factory hall: concrete / plate floors, painted walls, steel
    tables."""
    pool = FACTORY_TEXTURES[split]

    def texture(part: str) -> str:
        name = f"{split}/{pick(rng, pool[part])}.png"
        assert name in texture_names(split), name
        return name

    tints = FACTORY_TINTS[split]
    shade = float(rng.uniform(0.75, 0.95))
    floor = tuple(shade * c for c in tints["floor"]) + (1.0,)
    return {
        "floor": MaterialSpec(
            colour=floor, texture=texture("floor"), roughness=float(rng.uniform(0.6, 0.9))
        ),
        "wall": MaterialSpec(colour=(*tints["wall"], 1.0), texture=texture("wall"), roughness=0.9),
        "table": MaterialSpec(
            colour=(*tints["table"], 1.0),
            texture=texture("table"),
            roughness=float(rng.uniform(0.3, 0.5)),
            metallic=float(rng.uniform(0.5, 0.8)),
        ),
    }


@register_task
class FactoryPackingEnv(AEDBaseEnv):
    """
    **Task Description:**
    In a factory, an open box arrives on a conveyor belt at the operating table. Wait for it,
    put the product (lying on the table) into the box, then pick the box up and place it on
    the next conveyor belt, which carries it to the destination at the belt's end.

    **Randomizations:**
    - per environment: floor, wall and table factory materials, lighting, belt design and
      paint, box design, size and colour, product shape, size and colour
    - per episode: where the box starts on the incoming belt (out of reach) and its lateral
      offset, both belt speeds (0.10-0.14 m/s), product position and yaw

    **Success Conditions:**
    - the product is inside the box (its origin within the inner walls, 6 mm thick, above
      the box's bottom and below its rim) and the box, released, has reached the
      destination: on the outgoing belt (centre within 6 cm of the belt's centre line, bottom
      within 1.2 cm of the belt's surface) with its centre beyond x = `DESTINATION_X` = 0.30 m

    **Stages:** box arrived at the operating table, product in box, box picked (with the
    product), box delivered (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `product_not_in_box`: the product is put down beside the box, not into it (checked:
      the product out of the box, the box not delivered)
    - `no_grasp_box`: the gripper closes beyond the box's open end; the box is never picked
      up (checked: the box, packed, never lifted, still at the incoming belt)
    - `miss_belt`: the box is put down on the table 15 cm short of (or past) the outgoing
      belt's centre line (checked: the box, packed, was lifted, now rests off the belt).
      The onset is where the carry departs: short, where it stops while the clean carry
      goes on; past, where it goes on while the clean expert would put the box down
    """

    task_name = "FactoryPacking"
    catalogue_sizes = {"base": 36, "novel": 12}
    num_stages = 4
    error_kinds = ("product_not_in_box", "no_grasp_box", "miss_belt")
    recoverable_errors = ("product_not_in_box", "no_grasp_box", "miss_belt")
    max_episode_steps = 400
    eval_horizon = 400

    # --- catalogue --------------------------------------------------------------------------
    @classmethod
    def make_environment(cls, split: str, index: int) -> EnvironmentSpec:
        env = super().make_environment(split, index)
        rng = catalogue_rng(f"{cls.task_name}/factory", split, index)
        return dataclasses.replace(env, **factory_background(rng, split))

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        box_colour, product_colour, paint = pick(rng, object_colours(split), 3)
        box_size = (
            float(rng.uniform(0.09, 0.11)),
            float(rng.uniform(0.054, 0.062)),
            float(rng.uniform(0.045, 0.058)),
        )
        belt_texture = f"{split}/{pick(rng, FACTORY_TEXTURES[split]['belt'])}.png"
        return {
            "box": ObjectSpec(
                pick(rng, BOX_SHAPES[split]),
                box_size,
                MaterialSpec(colour=box_colour, roughness=float(rng.uniform(0.5, 0.9))),
            ),
            "product": ObjectSpec(
                pick(rng, PRODUCT_SHAPES[split]),
                (float(rng.uniform(0.03, 0.036)), float(rng.uniform(0.034, 0.044))),
                MaterialSpec(colour=product_colour, roughness=float(rng.uniform(0.3, 0.7))),
            ),
            "conveyor": ObjectSpec(
                pick(rng, CONVEYOR_SHAPES[split]),
                (BELT_WIDTH, float(rng.uniform(0.012, 0.02))),
                MaterialSpec(colour=paint, texture=belt_texture, roughness=0.5, metallic=0.3),
            ),
        }

    # --- scene ------------------------------------------------------------------------------
    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.in_belt = build_conveyor(
            self.scene, objects["conveyor"], "in_conveyor", IN_BELT_X, IN_BELT_Y, -1
        )
        self.out_belt = build_conveyor(
            self.scene, objects["conveyor"], "out_conveyor", OUT_BELT_X, OUT_BELT_Y, +1
        )
        self.box = build_packing_box(self.scene, objects["box"], "box")
        self.product = build_product(self.scene, objects["product"], "product")
        wall = self.env_spec.wall
        build_pillars(
            self.scene,
            dataclasses.replace(wall, colour=(0.55, 0.56, 0.6, 1.0)),
            PILLARS,
            -TABLE_HEIGHT,
        )

    def _initialize_task(self, rng: np.random.Generator) -> None:
        self.in_belt.speed = float(rng.uniform(*BELT_SPEED))
        self.out_belt.speed = float(rng.uniform(*BELT_SPEED))
        for belt in (self.in_belt, self.out_belt):
            belt.actor.set_pose(belt.home)
        x, y = rng.uniform(*BOX_START_X), IN_BELT_Y + rng.uniform(-0.015, 0.015)
        self.box.set_pose(
            Pose.create_from_pq(p=[x, y, BELT_TOP + 0.001], q=rotation_z(rng.uniform(-0.04, 0.04)))
        )
        px, py = sample_free_xy(rng, PRODUCT_REGION, 0.0, [])
        self.product.set_pose(
            Pose.create_from_pq(p=[px, py, 0.001], q=rotation_z(rng.uniform(-0.3, 0.3)))
        )
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)
        self.box_highest = torch.zeros(
            self.num_envs, device=self.device
        )  # the box's highest bottom so far

    def _before_simulation_step(self) -> None:
        for belt in (self.in_belt, self.out_belt):
            belt.drive(self.sim_timestep)

    # --- evaluation -------------------------------------------------------------------------
    @property
    def box_stop_x(self) -> float:
        """Where the box centre comes to rest against the incoming belt's end stop.

        (A box whose lips pass over the stop goes a little further: still arrived.)
        """
        return IN_BELT_X[0] + box_half_reach(self.env_spec.objects["box"])

    def box_arrived(self) -> torch.Tensor:
        p = self.box.pose.p
        on_belt = (torch.abs(p[:, 1] - IN_BELT_Y) < 0.06) & (torch.abs(p[:, 2] - BELT_TOP) < 0.012)
        return on_belt & (p[:, 0] < self.box_stop_x + 0.012)

    def product_in_box(self) -> torch.Tensor:
        length, width, height = self.env_spec.objects["box"].size
        local = (self.box.pose.inv() * self.product.pose).p
        inside_xy = (torch.abs(local[:, 0]) < length / 2 - WALL_THICKNESS) & (
            torch.abs(local[:, 1]) < width / 2 - WALL_THICKNESS
        )
        inside_z = (local[:, 2] > 0) & (local[:, 2] < height)
        return inside_xy & inside_z

    def box_on_out_belt(self) -> torch.Tensor:
        p = self.box.pose.p
        return (torch.abs(p[:, 1] - OUT_BELT_Y) < 0.06) & (torch.abs(p[:, 2] - BELT_TOP) < 0.012)

    def box_delivered(self) -> torch.Tensor:
        return self.box_on_out_belt() & (self.box.pose.p[:, 0] > DESTINATION_X)

    def evaluate(self) -> dict[str, torch.Tensor]:
        packed = self.product_in_box()
        grasped = self.agent.is_grasping(self.box)
        picked = grasped & (self.box.pose.p[:, 2] > BELT_TOP + 0.025) & packed
        delivered = self.box_delivered() & ~grasped
        success = delivered & packed
        stage = torch.where(
            success,
            4,
            torch.where(picked, 3, torch.where(packed, 2, torch.where(self.box_arrived(), 1, 0))),
        ).to(torch.int32)
        self.stage_reached = torch.maximum(self.stage_reached, stage)
        self.box_highest = torch.maximum(self.box_highest, self.box.pose.p[:, 2])
        # an empty box at the destination is out of reach for good
        fail = self.objects_off_table(self.box, self.product) | (delivered & ~packed)
        return {
            "success": success,
            "fail": fail,
            "stage": self.stage_reached.clone(),
            "is_grasped": grasped,
        }

    def state_entities(self) -> dict:
        return {"box": self.box, "product": self.product}

    def error_outcome(self, kind: str) -> str:
        problem = super().error_outcome(kind)
        if problem:
            return problem
        packed, delivered = bool(self.product_in_box()[0]), bool(self.box_delivered()[0])
        if kind == "product_not_in_box":
            if packed or bool(self.agent.is_grasping(self.product)[0]):
                return "the product is in the box or still held"
            return "the box was delivered" if delivered else ""
        if not packed:
            return "the product is not in the box"
        if bool(self.agent.is_grasping(self.box)[0]):
            return "the gripper still holds the box"
        lifted = float(self.box_highest[0]) - BELT_TOP
        if kind == "no_grasp_box":
            if lifted > 0.01:
                return f"the box was lifted {lifted * 100:.1f} cm"
            return "" if bool(self.box_arrived()[0]) else "the box left the incoming belt"
        if lifted < 0.02:
            return f"the box was never carried (lifted {lifted * 100:.1f} cm)"
        if bool(self.box_on_out_belt()[0]):
            return "the box is on the outgoing belt"
        return "" if float(self.box.pose.p[0, 2]) < 0.01 else "the box does not rest on the table"

    # --- expert -----------------------------------------------------------------------------
    def _pose_of(self, actor) -> np.ndarray:
        return actor.pose.p[0].cpu().numpy().astype(np.float64)

    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        """Pack the product (unless it already is), then move the box to the outgoing belt."""
        kind = error.kind if error else None
        if expert.gripper != OPEN:  # after a failed attempt the fingers may still be closed
            expert.move_by([0.0, 0.0, 0.02])
            expert.open_gripper()
        if not bool(self.product_in_box()[0]):
            if not self._pack_product(expert, kind):
                return
        if bool(self.box_on_out_belt()[0]):
            self._rest_until_delivered(expert, float(self.box.pose.p[0, 0]))  # already on its way
            return
        if not self._pick_box(expert, kind):
            return
        self._place_box(expert, kind)

    def _pack_product(self, expert: ScriptedExpert, kind: str | None) -> bool:
        """Pick the product, wait for the box, drop it in. False after an injected error."""
        width, height = self.env_spec.objects["product"].size
        _, _, box_height = self.env_spec.objects["box"].size
        grip = max(height / 2, height - 0.016)  # TCP height above the product's bottom
        product = self._pose_of(self.product)
        grasp = product + np.array([0.0, 0.0, grip])
        expert.move_to(grasp + [0, 0, expert.rng.uniform(0.07, 0.12)] + expert.jitter(0.015))
        expert.move_to(grasp, speed=expert.speed * 0.6, tol=0.004)
        expert.close_gripper()
        box = self._pose_of(self.box)
        rim = box[2] + box_height
        release_z = rim + expert.rng.uniform(0.012, 0.02) + grip
        expert.move_by([0.0, 0.0, release_z + 0.03 - expert.tcp[2]], speed=expert.speed * 0.7)
        # hold the product over the end of the incoming belt until the box is there
        stop = np.array([min(box[0], self.box_stop_x), box[1], release_z + 0.03])
        expert.move_to(stop + expert.jitter(0.01))
        for _ in range(150):
            if bool(self.box_arrived()[0]):
                break
            expert.wait(1)
        box = self._pose_of(self.box)
        release = np.array([box[0], box[1], release_z])
        if kind == "product_not_in_box":  # set it down on the table beside the box instead
            expert.mark_error()
            length = self.env_spec.objects["box"].size[0]
            if expert.error_rng.random() < 0.5:
                beside = np.array([box[0] - length / 2 - 0.075, box[1] - 0.02, grip + 0.01])
            else:
                beside = np.array([box[0] - 0.02, IN_BELT_Y - 0.17, grip + 0.01])
            expert.move_to(np.array([beside[0], beside[1], expert.tcp[2]]))
            expert.move_to(beside, speed=expert.speed * 0.6)
            expert.open_gripper()
            expert.move_by([0.0, 0.0, 0.08])
            expert.wait(4)
            return False
        expert.move_to(release, speed=expert.speed * 0.6, tol=0.004)
        expert.open_gripper()
        expert.move_by([0.0, 0.0, 0.06], speed=expert.speed * 0.7)
        return True

    def _pick_box(self, expert: ScriptedExpert, kind: str | None) -> bool:
        """Grip the box across its long walls and lift it. False after an injected error."""
        length, _, height = self.env_spec.objects["box"].size
        box = self._pose_of(self.box)
        grasp = box + np.array([0.0, 0.0, height - 0.018])
        hover = grasp + np.array([0.0, 0.0, expert.rng.uniform(0.06, 0.1)])
        expert.move_to(hover + expert.jitter(0.01))
        expert.move_to(hover, speed=expert.speed * 0.6, tol=0.003)
        if kind == "no_grasp_box":  # close the fingers on the air beyond the box's open end
            expert.mark_error()
            expert.move_to(
                grasp + np.array([length / 2 + 0.035, 0.0, 0.0]),
                speed=expert.speed * 0.6,
                tol=0.004,
            )
            expert.close_gripper()
            expert.move_by([0.0, 0.0, expert.rng.uniform(0.08, 0.12)], speed=expert.speed * 0.7)
            expert.wait(4)
            return False
        expert.move_to(grasp, speed=expert.speed * 0.5, tol=0.003)
        expert.close_gripper()
        carry = BELT_TOP + height + expert.rng.uniform(0.06, 0.1) - 0.018
        expert.move_by([0.0, 0.0, carry - expert.tcp[2]], speed=expert.speed * 0.6)
        return True

    def _place_box(self, expert: ScriptedExpert, kind: str | None) -> None:
        """Set the box down on the outgoing belt (or, with `miss_belt`, beside it) and let go."""
        height = self.env_spec.objects["box"].size[2]
        drop_x = expert.rng.uniform(-0.06, 0.0)
        target = np.array(
            [
                drop_x,
                OUT_BELT_Y + expert.rng.uniform(-0.01, 0.01),
                BELT_TOP + 0.008 + height - 0.018,
            ]
        )
        over_belt = np.array([target[0], target[1], expert.tcp[2]])
        if kind == "miss_belt":  # on the table short of the belt, or past it
            short = bool(expert.error_rng.random() < 0.5)
            miss_y = OUT_BELT_Y + (MISS_OFFSET if short else -MISS_OFFSET)
            target = np.array([target[0], miss_y, target[2] - BELT_TOP])
            if short:  # carry as the clean expert does, stop before the belt
                expert.move_to(over_belt, stop_before=lambda waypoint: bool(waypoint[1] < miss_y))
            else:  # carry as the clean expert does, then go on past the belt
                expert.move_to(over_belt)
            expert.mark_error()
            expert.move_to(np.array([expert.tcp[0], miss_y, expert.tcp[2]]))
        else:
            expert.move_to(over_belt)
        expert.move_to(target, speed=expert.speed * 0.5, tol=0.004)
        expert.open_gripper()
        expert.move_by([0.0, 0.0, 0.08], speed=expert.speed * 0.7)
        self._rest_until_delivered(expert, target[0])

    def _rest_until_delivered(self, expert: ScriptedExpert, box_x: float) -> None:
        """Rest while the belt carries the box (released at `box_x`) to the destination.

        As long after a miss as after a delivery: the time the belt needs, then 4 steps.
        """
        travel = max(DESTINATION_X + 0.02 - box_x, 0.0) / self.out_belt.speed
        expert.wait(int(np.ceil(travel / self.control_timestep)) + 4)

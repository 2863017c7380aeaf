"""Move Glass Cup: carry a glass of water to the coaster the demonstrations chose, spilling
nothing."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from aed_tasks.base_env import AEDBaseEnv, sample_free_xy
from aed_tasks.catalogue import MaterialSpec, ObjectSpec, object_colours, pick, texture_names
from aed_tasks.expert import MAX_DELTA, ErrorSpec, ScriptedExpert
from aed_tasks.objects.glass import (
    build_coaster,
    build_glass,
    build_water,
    coaster_support_radius,
    drop_positions,
    drop_spots,
    glass_geometry,
)
from aed_tasks.registration import register_task
from aed_tasks.scene import rotation_z

GLASS_SHAPES = {
    "base": ("glass_tumbler", "glass_tapered"),
    "novel": ("glass_octagonal", "glass_round_bottom"),
}
COASTER_SHAPES = {
    "base": ("coaster_round", "coaster_square"),
    "novel": ("coaster_hexagon", "coaster_oval"),
}
GLASS_REGION = (-0.22, -0.09, -0.2, 0.2)  # x0, x1, y0, y1 on the table top
COASTER_REGION = (-0.03, 0.12, -0.24, 0.24)
TABLE_REACH = (-0.26, 0.15, -0.28, 0.28)  # where the expert may put the glass down
FILL = (
    0.55,
    0.7,
)  # water level as a fraction of the glass height (the spill needs headroom under 6 cm)
RIM_CLEARANCE = (
    0.010  # grasp this close under the rim: the palm (3.7 cm above the tcp) leaves a gap
)
MAX_DROPS = 28  # drops in the fullest glass
SPILL_MARGIN = 0.003  # a drop this far outside the wall has left the glass
UPRIGHT_TILT = 15.0  # degrees: the glass stands upright with its axis within this of vertical
UNTOUCHED = 0.01  # m: `no_grasp` leaves the glass within this of its start (it never moved)
OFF_HEADING = 50.0  # degrees: `off_coaster` heads this far off the way to the target coaster
DIP_UP, DIP_DOWN, DIP_ASIDE = (
    3,
    2,
    2,
)  # `spill`: steps at full speed up, down, then down and sideways


@register_task
class MoveGlassCupEnv(AEDBaseEnv):
    """
    **Task Description:**
    Pick up a glass of water and put it down on the coaster that the expert used in the
    demonstrations, without spilling; a second coaster of another colour is a task
    distractor. The water is simulated: light, slippery spheres that slosh in the hollow
    glass and fly out when it is jerked.

    **Randomizations:**
    - per environment: table, floor and wall textures, lighting, glass shape, size and
      tint, water level, coaster shapes, sizes, colours and textures (target and
      distractor differ in colour)
    - per episode: glass position in a 13 x 40 cm region, both coaster positions and yaws
      (which side the target is on varies), the drops' arrangement in the glass

    **Success Conditions:**
    - the glass stands upright on the target coaster, released by the gripper: its centre
      within 0.75 of the coaster's support radius, its base within 6 mm of the coaster's top,
      its axis within 15 degrees of vertical
    - no water was spilled: every drop stayed inside the glass all episode (a drop is out
      3 mm beyond the outer wall, 1 cm below the base or 5 cm above the rim)

    **Stages:** picked (lifted while grasped), placed (success).

    **Behaviour Errors** (each episode's end is checked to show its failure, `error_outcome`):
    - `no_grasp`: the gripper closes in front of or behind the glass (its fingers 2 cm off
      the wall); it is never picked up (checked: the glass never moved by 1 cm, no spill)
    - `spill`: part of the way over (25-50% of the carry) the carry turns jerky: the arm jerks
      the glass up, down and sideways at full speed, up to 4 times until a drop flies out
      (checked: water spilled); the onset is where the smooth carry stops
    - `off_coaster`: the glass is carried to a spot on the table 12-22 cm from the target
      coaster, heading at least 50 degrees off the way to it where the table allows, and put
      down there (checked: released, upright, its footprint clear of both coasters, no spill)
    """

    task_name = "MoveGlassCup"
    catalogue_sizes = {"base": 42, "novel": 20}
    num_stages = 2
    error_kinds = ("no_grasp", "spill", "off_coaster")
    recoverable_errors = ("no_grasp", "off_coaster")
    max_episode_steps = 300
    eval_horizon = 300

    @classmethod
    def sample_objects(
        cls, rng: np.random.Generator, split: str, index: int
    ) -> dict[str, ObjectSpec]:
        glass_hue, target_colour, distractor_colour = pick(rng, object_colours(split), 3)
        return {
            "glass": sample_glass(rng, split, glass_hue),
            "target_coaster": sample_coaster(rng, split, target_colour),
            "distractor_coaster": sample_coaster(rng, split, distractor_colour),
        }

    def _load_task(self, options: dict) -> None:
        objects = self.env_spec.objects
        self.glass = build_glass(self.scene, objects["glass"], "glass")
        self.drops = build_water(self.scene, objects["glass"], "water")
        self.target_coaster = build_coaster(self.scene, objects["target_coaster"], "target_coaster")
        self.distractor_coaster = build_coaster(
            self.scene, objects["distractor_coaster"], "distractor_coaster"
        )
        self.geometry = glass_geometry(objects["glass"])
        # the outer wall as tensors, for the per-step spill check
        self.wall_radii, self.wall_heights = (
            torch.tensor(v, dtype=torch.float32, device=self.device)
            for v in self.geometry.wall.T.copy()
        )

    def _initialize_task(self, rng: np.random.Generator) -> None:
        keep_out: list[tuple[float, float, float]] = []
        for coaster, key in (
            (self.target_coaster, "target_coaster"),
            (self.distractor_coaster, "distractor_coaster"),
        ):
            radius = self.env_spec.objects[key].size[0] / 2
            x, y = sample_free_xy(rng, COASTER_REGION, radius + 0.025, keep_out)
            keep_out.append((x, y, radius))
            self._place(coaster, [x, y, 0.001], rng.uniform(0, 2 * np.pi))
        x, y = sample_free_xy(rng, GLASS_REGION, self.geometry.diameter / 2 + 0.03, keep_out)
        # turn the glass by whole wall boxes so that flats face the fingers (world +-y)
        yaw = 2 * np.pi / self.geometry.segments * int(rng.integers(self.geometry.segments))
        self._place(self.glass, [x, y, 0.001], yaw)
        spots = drop_positions(self.env_spec.objects["glass"], rng)
        c, s = np.cos(yaw), np.sin(yaw)
        for drop, (dx, dy, dz) in zip(self.drops, spots, strict=True):
            self._place(drop, [x + c * dx - s * dy, y + s * dx + c * dy, 0.001 + dz], 0.0)
        self.stage_reached = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device)
        self.spilled = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        self.glass_start = self.glass.pose.p.clone()
        self.glass_travel = torch.zeros(
            self.num_envs, device=self.device
        )  # farthest from the start so far

    def _place(self, actor, position: list[float], yaw: float) -> None:
        actor.set_pose(
            Pose.create_from_pq(p=position, q=rotation_z(yaw))
        )  # (ManiSkill zeroed velocities)

    # --- evaluation -------------------------------------------------------------------------
    def drops_outside(self) -> torch.Tensor:
        """(num_envs, drops): which drops are outside the glass (beyond its wall, below or far
        above)."""
        frame = self.glass.pose.to_transformation_matrix()  # (b, 4, 4)
        drops = torch.stack([d.pose.p for d in self.drops], dim=1)  # (b, n, 3)
        local = torch.einsum("bji,bnj->bni", frame[:, :3, :3], drops - frame[:, None, :3, 3])
        radial = torch.linalg.norm(local[..., :2], dim=-1)
        beyond_wall = (
            radial > interp(local[..., 2], self.wall_heights, self.wall_radii) + SPILL_MARGIN
        )
        below = local[..., 2] < -0.01
        flown = local[..., 2] > self.geometry.height + 0.05
        return beyond_wall | below | flown

    def _on_target(self) -> torch.Tensor:
        spec = self.env_spec.objects["target_coaster"]
        offset = self.glass.pose.p - self.target_coaster.pose.p
        centred = torch.linalg.norm(offset[:, :2], dim=1) < coaster_support_radius(spec) * 0.75
        resting = (offset[:, 2] - spec.size[1]).abs() < 0.006
        upright = self.glass.pose.to_transformation_matrix()[:, 2, 2] > np.cos(
            np.deg2rad(UPRIGHT_TILT)
        )
        return centred & resting & upright

    def evaluate(self) -> dict[str, torch.Tensor]:
        grasped = self.agent.is_grasping(self.glass)
        lifted = self.glass.pose.p[:, 2] > 0.03
        outside = self.drops_outside()
        self.spilled = self.spilled | outside.any(dim=1)
        moved = torch.linalg.norm(self.glass.pose.p - self.glass_start, dim=1)
        self.glass_travel = torch.maximum(self.glass_travel, moved)
        placed = self._on_target() & ~grasped
        success = placed & ~self.spilled
        stage = torch.where(success, 2, torch.where(grasped & lifted, 1, 0)).to(torch.int32)
        self.stage_reached = torch.maximum(self.stage_reached, stage)
        return {
            "success": success,
            "fail": self.objects_off_table(self.glass),
            "stage": self.stage_reached.clone(),
            "is_grasped": grasped,
            "spilled": self.spilled.clone(),
            "drops_outside": outside.sum(dim=1),
        }

    def state_entities(self) -> dict:
        return {
            "glass": self.glass,
            "target_coaster": self.target_coaster,
            "distractor_coaster": self.distractor_coaster,
        }

    def error_outcome(self, kind: str) -> str:
        super().error_outcome(kind)
        info = self.evaluate()
        spilled = bool(info["spilled"][0])
        if kind == "spill":
            return "" if spilled else "no drop left the glass"
        if bool(info["is_grasped"][0]):
            return "the gripper still holds the glass"
        if spilled:
            return f"water was spilled too ({int(info['drops_outside'][0])} drops out)"
        if kind == "no_grasp":
            travel = float(self.glass_travel[0])
            return "" if travel < UNTOUCHED else f"the glass moved by {travel * 100:.1f} cm"
        glass = self.glass.pose.p[0].cpu().numpy()
        if self.glass.pose.to_transformation_matrix()[0, 2, 2] < np.cos(np.deg2rad(UPRIGHT_TILT)):
            return "the glass fell over"
        for coaster, key in (
            (self.target_coaster, "target_coaster"),
            (self.distractor_coaster, "distractor_coaster"),
        ):
            distance = float(np.linalg.norm(glass[:2] - coaster.pose.p[0, :2].cpu().numpy()))
            if (
                distance
                < coaster_support_radius(self.env_spec.objects[key]) + self.geometry.diameter / 2
            ):
                return (
                    f"the glass stands {distance * 100:.1f} cm from the centre of the "
                    f"{key.replace('_', ' ')}"
                )
        return ""

    # --- expert -----------------------------------------------------------------------------
    def expert_script(self, expert: ScriptedExpert, error: ErrorSpec | None) -> None:
        kind = error.kind if error else None
        glass = self.glass.pose.p[0].cpu().numpy().astype(np.float64)
        height = self.geometry.height
        grasp = glass + np.array([0.0, 0.0, height - RIM_CLEARANCE])
        hover = glass + np.array([0.0, 0.0, height + expert.rng.uniform(0.05, 0.09)])

        expert.move_to(hover + expert.jitter(0.02))
        if (
            kind == "no_grasp"
        ):  # close the fingers in front of (or behind) the glass instead of around it
            expert.mark_error()
            side = np.sign(expert.rng.uniform(-1, 1)) * (self.geometry.diameter / 2 + 0.03)
            expert.move_to(grasp + np.array([side, 0.0, 0.0]), speed=expert.speed * 0.6)
        else:
            expert.move_to(grasp, speed=expert.speed * 0.6)
        expert.close_gripper()
        carry = expert.speed * 0.8  # water on board: slower, with smooth starts and stops
        carry_to(expert, expert.tcp + np.array([0.0, 0.0, expert.rng.uniform(0.07, 0.11)]), carry)

        coaster = self.target_coaster.pose.p[0].cpu().numpy().astype(np.float64)
        coaster_top = coaster[2] + self.env_spec.objects["target_coaster"].size[1]
        put_down = np.array([coaster[0], coaster[1], coaster_top + grasp[2] - glass[2] + 0.004])
        if kind == "off_coaster":  # head for a spot on the table instead
            expert.mark_error()
            put_down[:2] = self._table_spot(
                expert.error_rng, expert.tcp[:2], put_down[:2], glass[:2]
            )
            put_down[2] = grasp[2] - glass[2] + 0.005
        above = np.array([put_down[0], put_down[1], expert.tcp[2]]) + expert.jitter(0.01)
        # `spill`: carried as the clean expert does until part of the way over, then a lurch
        stop_at = expert.error_rng.uniform(0.25, 0.5) if kind == "spill" else None
        if carry_to(expert, above, carry, stop_at=stop_at):
            expert.mark_error()
            lurch(expert, above)
            carry_to(expert, above, carry)
        carry_to(expert, put_down, carry * 0.6)
        expert.open_gripper()
        expert.move_by([0.0, 0.0, 0.07])
        expert.wait(4)

    def _table_spot(
        self, rng: np.random.Generator, here: np.ndarray, target: np.ndarray, start: np.ndarray
    ) -> np.ndarray:
        """A spot on the table clear of both coasters, 12-22 cm from the target (a missed
        placement), in a direction from `here` at least `OFF_HEADING` degrees off the target's
        (or as far off as there is): the path visibly heads elsewhere from its first steps."""
        radius = self.geometry.diameter / 2 + 0.015
        clear = [
            (
                *c.pose.p[0, :2].cpu().numpy().astype(np.float64),
                self.env_spec.objects[k].size[0] / np.sqrt(2),
            )
            for c, k in (
                (self.target_coaster, "target_coaster"),
                (self.distractor_coaster, "distractor_coaster"),
            )
        ]
        heading = target - here
        best, best_cos = None, 1.0
        for _ in range(400):
            angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(0.12, 0.22)
            spot = target + distance * np.array([np.cos(angle), np.sin(angle)])
            inside = (
                TABLE_REACH[0] < spot[0] < TABLE_REACH[1]
                and TABLE_REACH[2] < spot[1] < TABLE_REACH[3]
            )
            if not inside or any(np.hypot(*(spot - [x, y])) <= r + radius for x, y, r in clear):
                continue
            way = spot - here
            cos = way @ heading / max(np.linalg.norm(way) * np.linalg.norm(heading), 1e-9)
            if cos < np.cos(np.deg2rad(OFF_HEADING)):
                return spot
            if cos < best_cos:
                best, best_cos = spot, cos
        if best is not None:  # far from the target, no spot turns that much: the most turned one
            return best
        return start  # nowhere else: put it back where it stood


def sample_glass(rng: np.random.Generator, split: str, hue: tuple[float, ...]) -> ObjectSpec:
    """A glass: shape, size, a pale tint of a split colour, and how much water it holds."""
    tint = tuple(float(0.72 + 0.28 * c) for c in hue[:3]) + (1.0,)
    spec = ObjectSpec(
        pick(rng, GLASS_SHAPES[split]),
        (
            float(rng.uniform(0.05, 0.06)),
            float(rng.uniform(0.09, 0.12)),
            64.0,
            float(rng.uniform(0.0062, 0.0072)),
        ),
        MaterialSpec(colour=tint, roughness=0.05),
    )
    spots = drop_spots(spec, np.random.default_rng(0))
    level = rng.uniform(*FILL) * spec.size[1]
    count = int(np.clip((spots[:, 2] + spec.size[3] <= level).sum(), 8, MAX_DROPS))
    return ObjectSpec(spec.shape, (*spec.size[:2], float(count), spec.size[3]), spec.material)


def sample_coaster(rng: np.random.Generator, split: str, colour: tuple[float, ...]) -> ObjectSpec:
    """A thin coaster of a split shape and colour, plain or under a split texture."""
    texture = pick(rng, texture_names(split)) if rng.random() < 0.5 else None
    size = (float(rng.uniform(0.095, 0.115)), float(rng.uniform(0.004, 0.008)))
    return ObjectSpec(
        pick(rng, COASTER_SHAPES[split]),
        size,
        MaterialSpec(colour=tuple(colour), texture=texture, roughness=0.8),
    )


def interp(x: torch.Tensor, xp: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
    """np.interp for tensors (xp increasing, x clamped to its range)."""
    x = x.clamp(xp[0], xp[-1])
    index = torch.searchsorted(xp, x.contiguous(), right=True).clamp(1, len(xp) - 1)
    x0, x1, f0, f1 = xp[index - 1], xp[index], fp[index - 1], fp[index]
    return f0 + (f1 - f0) * (x - x0) / (x1 - x0).clamp_min(1e-9)


def carry_to(
    expert: ScriptedExpert,
    target: np.ndarray,
    speed: float,
    ramp: int = 8,
    settle: int = 10,
    stop_at: float | None = None,
) -> bool:
    """Follow a planned path to `target` with raised-cosine speed ramps: no jolt spills the water.

    With `stop_at` (a fraction of the path), stop there at cruise speed, with no ramp down, and
    return True (the `spill` error's departure); else return False.
    """
    path = expert.plan(np.asarray(target, dtype=np.float64))
    lengths = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc, total = np.concatenate([[0.0], np.cumsum(lengths)]), float(lengths.sum())
    for s in np.cumsum(speed_profile(total, speed, ramp)):
        if stop_at is not None and s > stop_at * total:
            return True
        waypoint = np.stack([np.interp(s, arc, path[:, i]) for i in range(3)])
        expert.step(waypoint - expert.tcp)
    if stop_at is not None:  # too short a path to stop on the way: stop at its end
        return True
    for _ in range(settle):
        error = target - expert.tcp
        if np.linalg.norm(error) < 0.005:
            break
        expert.step(error * 0.5)
    return False


def speed_profile(length: float, speed: float, ramp: int) -> np.ndarray:
    """Per-step distances summing to `length`: cosine ramp up, cruise at `speed`, ramp down."""
    if length < 1e-4:
        return np.zeros(0)
    up = (1 - np.cos(np.pi * (np.arange(ramp) + 0.5) / ramp)) / 2
    cruise = max(int(np.ceil((length - ramp * speed) / speed)), 0)
    steps = np.concatenate([up, np.ones(cruise), up[::-1]]) * speed
    return steps * length / steps.sum()


def lurch(expert: ScriptedExpert, toward: np.ndarray, max_dips: int = 4) -> None:
    """A jerky carry (`spill`): the arm jerks the glass up and at once down at full speed, so
    the water leaves the floor and rises above the rim, then slides it sideways from under the
    water. Repeated back to back (at most `max_dips` times, alternately ahead and back) until a
    drop is out or the glass has left the grasp (also a failure), then back to the carrying
    height. One vertical jerk throws the water about 6 cm up the glass (the arm tops out near
    0.75 m/s), so the glasses are filled to within 3-6 cm of the rim; still about one episode
    in eight keeps every drop (`error_outcome` rejects it)."""
    base = expert.base
    carry_z = expert.tcp[2]
    for dip in range(max_dips):
        way = np.asarray(toward, dtype=np.float64)[:2] - expert.tcp[:2]
        side = way / max(np.linalg.norm(way), 1e-9) * (1.0 if dip % 2 == 0 else -1.0)
        for _ in range(DIP_UP):
            expert.step(np.array([0.0, 0.0, MAX_DELTA]))
        for _ in range(DIP_DOWN):  # straight down: the water leaves the floor
            expert.step(np.array([0.0, 0.0, -MAX_DELTA]))
        for _ in range(DIP_ASIDE):  # and, still going down, slides from under the water
            expert.step(np.array([*side, -1.0]) * MAX_DELTA)
        if bool(base.spilled[0]) or not bool(base.agent.is_grasping(base.glass)[0]):
            break
    for _ in range(3):  # back to the carrying height
        expert.step(np.array([0.0, 0.0, carry_z - expert.tcp[2]]))

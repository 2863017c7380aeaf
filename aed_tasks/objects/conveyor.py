"""Factory objects: conveyor belts moved by contact, open-top packing boxes, products, pillars.

A conveyor is a static frame (body, side rails, end stop) plus a thin *kinematic* belt slab.
Every physics substep the slab is put back at its home pose and given a kinematic target
`speed * dt` further along the belt: PhysX then sees a surface moving at `speed`, and
whatever rests on it is carried by friction alone, while the slab itself never drifts
(PhysX's classic conveyor trick). Nothing carried is ever teleported.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from aed_tasks.assets import mesh_path
from aed_tasks.catalogue import MaterialSpec, ObjectSpec
from aed_tasks.scene import UPRIGHT, physical_material, render_material

ALONG_Y = [0.7071068, 0, 0, 0.7071068]  # turns SAPIEN's x-aligned cylinders to y

BELT_TOP = 0.05  # height of every belt surface above the table top
BELT_SKIN = 0.006  # thickness of the moving belt slab
RAIL_THICKNESS = 0.008
END_STOP_HEIGHT = 0.035  # above the belt surface
WALL_THICKNESS = 0.006  # of the packing boxes
FLANGE_REACH = 0.014  # how far a flanged box's lips stand out at its x ends
HANDLE_REACH = 0.02  # how far a handled box's tabs stand out at its x ends
RUBBER = MaterialSpec(colour=(0.16, 0.16, 0.17, 1.0), roughness=0.85)


@dataclass
class ConveyorBelt:
    """A belt slab that carries what rests on it along `direction` at `speed` (m/s)."""

    actor: Actor
    home: sapien.Pose
    direction: np.ndarray
    speed: float = 0.0

    def drive(self, dt: float) -> None:
        """Before a physics substep: back home, then a kinematic target `speed * dt` ahead."""
        target = sapien.Pose(p=self.home.p + self.direction * self.speed * dt, q=self.home.q)
        for entity, body in zip(self.actor._objs, self.actor._bodies, strict=True):
            entity.set_pose(self.home)
            body.set_kinematic_target(target)


def build_conveyor(
    scene: ManiSkillScene,
    spec: ObjectSpec,
    name: str,
    x_range: tuple[float, float],
    y: float,
    direction: int,
) -> ConveyorBelt:
    """A belt along x over `x_range` at lateral position `y`, running towards `direction` (+1/-1).

    `spec.size` = (belt width, rail height); `spec.material`'s colour paints the frame and its
    texture covers the belt. Designs: `conveyor_railed*` has plain end caps,
    `conveyor_rollered*` shows drum rollers at both ends and a motor housing.
    """
    width, rail_height = spec.size
    x0, x1 = x_range
    length, cx = x1 - x0, (x0 + x1) / 2
    paint = render_material(dataclasses.replace(spec.material, texture=None))
    frame = scene.create_actor_builder()
    body_h = BELT_TOP - BELT_SKIN
    _add_box(
        frame, [cx, y, body_h / 2], [length / 2, width / 2 + RAIL_THICKNESS, body_h / 2], paint
    )
    for side in (-1, 1):  # side rails: they keep carried boxes on the belt
        rail_y = y + side * (width / 2 + RAIL_THICKNESS / 2)
        rail_z = (body_h + BELT_TOP + rail_height) / 2
        _add_box(
            frame,
            [cx, rail_y, rail_z],
            [length / 2, RAIL_THICKNESS / 2, (BELT_TOP + rail_height - body_h) / 2],
            paint,
        )
    stop_x = x1 if direction > 0 else x0  # the downstream end: an end stop holds what arrives
    stop_paint = render_material(MaterialSpec(colour=(0.12, 0.12, 0.12, 1.0), roughness=0.6))
    _add_box(
        frame,
        [stop_x + direction * 0.008, y, (body_h + BELT_TOP + END_STOP_HEIGHT) / 2],
        [0.008, width / 2 + RAIL_THICKNESS, (BELT_TOP + END_STOP_HEIGHT - body_h) / 2],
        stop_paint,
    )
    if spec.shape.startswith("conveyor_rollered"):
        for end in (x0, x1):
            frame.add_cylinder_visual(
                pose=sapien.Pose(p=[end, y, BELT_TOP / 2], q=ALONG_Y),
                radius=BELT_TOP / 2,
                half_length=width / 2 + RAIL_THICKNESS,
                material=render_material(RUBBER),
            )
        motor_x = x0 + 0.06 if direction > 0 else x1 - 0.06
        frame.add_box_visual(
            pose=sapien.Pose(p=[motor_x, y + np.sign(y) * (width / 2 + 0.035), 0.03]),
            half_size=[0.04, 0.025, 0.03],
            material=paint,
        )
    else:
        for end in (x0, x1):
            frame.add_box_visual(
                pose=sapien.Pose(p=[end, y, body_h / 2]),
                half_size=[0.01, width / 2 + RAIL_THICKNESS + 0.004, body_h / 2 + 0.004],
                material=stop_paint,
            )
    frame.initial_pose = sapien.Pose()
    frame.build_static(name=f"{name}_frame")

    belt = scene.create_actor_builder()
    half = [length / 2, width / 2, BELT_SKIN / 2]
    surface = MaterialSpec(texture=spec.material.texture, roughness=RUBBER.roughness)
    belt.add_box_collision(half_size=half, material=physical_material(1.0))
    belt.add_box_visual(half_size=half, material=render_material(surface))
    home = sapien.Pose(p=[cx, y, BELT_TOP - BELT_SKIN / 2])
    belt.initial_pose = home
    actor = belt.build_kinematic(name=f"{name}_belt")
    return ConveyorBelt(actor=actor, home=home, direction=np.array([float(direction), 0.0, 0.0]))


def _add_box(
    builder,
    centre,
    half,
    material,
    collision: bool = True,
    density: float = 500.0,
    friction: float = 0.9,
) -> None:
    pose = sapien.Pose(p=list(centre))
    if collision:
        builder.add_box_collision(
            pose=pose, half_size=list(half), density=density, material=physical_material(friction)
        )
    builder.add_box_visual(pose=pose, half_size=list(half), material=material)


def build_packing_box(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, density: float = 450.0
) -> Actor:
    """An open-top box of `spec.size` = (length x, width y, height), origin at its bottom centre.

    Five boxes (floor and four walls) plus the design's extras, none of which widens the box
    along y: the gripper closes along y over the two long walls. Designs: `box_plain*`,
    `box_flanged*` (lips along the x ends), `box_handled*` (handle tabs at the x ends),
    `box_cornered*` (corner posts standing above the rim).
    """
    length, width, height = spec.size
    t = WALL_THICKNESS
    material = render_material(spec.material)
    builder = scene.create_actor_builder()
    _add_box(builder, [0, 0, t / 2], [length / 2, width / 2, t / 2], material, density=density)
    for side in (-1, 1):
        _add_box(
            builder,
            [0, side * (width - t) / 2, height / 2],
            [length / 2, t / 2, height / 2],
            material,
            density=density,
        )
        _add_box(
            builder,
            [side * (length - t) / 2, 0, height / 2],
            [t / 2, width / 2 - t, height / 2],
            material,
            density=density,
        )
    for side in (-1, 1):
        if spec.shape.startswith("box_flanged"):
            _add_box(
                builder,
                [side * (length + FLANGE_REACH) / 2, 0, height - t / 2],
                [FLANGE_REACH / 2, width / 2, t / 2],
                material,
                density=density,
            )
        elif spec.shape.startswith("box_handled"):
            _add_box(
                builder,
                [side * (length + HANDLE_REACH) / 2, 0, height * 0.7],
                [HANDLE_REACH / 2, width * 0.28, 0.005],
                material,
                density=density,
            )
        elif spec.shape.startswith("box_cornered"):
            for side_y in (-1, 1):
                post = [
                    side * (length / 2 - t - 0.005),
                    side_y * (width / 2 - t - 0.005),
                    (height + 0.01) / 2,
                ]
                _add_box(
                    builder, post, [0.005, 0.005, (height + 0.01) / 2], material, density=density
                )
    builder.initial_pose = sapien.Pose()
    return builder.build(name=name)


def box_half_reach(spec: ObjectSpec) -> float:
    """Half the packing box's outer length along x, extras included: where an end stop meets it."""
    length = spec.size[0]
    if spec.shape.startswith("box_handled"):
        return length / 2 + HANDLE_REACH
    if spec.shape.startswith("box_flanged"):
        return length / 2 + FLANGE_REACH
    return length / 2


def build_product(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, density: float = 500.0
) -> Actor:
    """A small product of `spec.size` = (width, height), origin at its bottom centre.

    `product_carton*` is a box, `product_can*` a cylinder; any other shape is a revolved
    mesh of the asset pool (its convex hull collides).
    """
    width, height = spec.size
    material = render_material(spec.material)
    grip = physical_material(1.2)
    builder = scene.create_actor_builder()
    if spec.shape.startswith("product_carton"):
        half = [width * 0.6, width / 2, height / 2]
        builder.add_box_collision(
            pose=sapien.Pose(p=[0, 0, height / 2]), half_size=half, density=density, material=grip
        )
        builder.add_box_visual(
            pose=sapien.Pose(p=[0, 0, height / 2]), half_size=half, material=material
        )
    elif spec.shape.startswith("product_can"):
        pose = sapien.Pose(p=[0, 0, height / 2], q=UPRIGHT)
        builder.add_cylinder_collision(
            pose=pose, radius=width / 2, half_length=height / 2, density=density, material=grip
        )
        builder.add_cylinder_visual(
            pose=pose, radius=width / 2, half_length=height / 2, material=material
        )
    else:
        path, scale = str(mesh_path(spec.shape)), [width, width, height]
        builder.add_convex_collision_from_file(path, scale=scale, density=density, material=grip)
        builder.add_visual_from_file(path, scale=scale, material=material)
    builder.initial_pose = sapien.Pose()
    return builder.build(name=name)


def build_pillars(
    scene: ManiSkillScene,
    material: MaterialSpec,
    positions: list[tuple[float, float]],
    floor_z: float,
) -> None:
    """Static square pillars from the floor up, the factory hall behind the robot."""
    builder = scene.create_actor_builder()
    paint = render_material(material)
    for x, y in positions:
        builder.add_box_visual(
            pose=sapien.Pose(p=[x, y, floor_z + 1.25]), half_size=[0.09, 0.09, 1.25], material=paint
        )
    builder.initial_pose = sapien.Pose()
    builder.build_static(name="pillars")

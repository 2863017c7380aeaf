"""Building an environment's room from its spec: floor, wall, table, lights, clutter.

Geometry is fixed across environments (the robot stands at the table's near edge, the
table top is z = 0); only materials, lights and clutter change, as in the paper.
"""

from __future__ import annotations

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from aed_tasks.assets import load_texture, mesh_path
from aed_tasks.catalogue import EnvironmentSpec, MaterialSpec, ObjectSpec

TABLE_HALF_SIZE = (0.62, 0.75)  # x, y; the top spans x in [-0.77, 0.47]
TABLE_CENTER_X = -0.15
TABLE_THICKNESS = 0.04
TABLE_HEIGHT = 0.76  # floor at z = -TABLE_HEIGHT
WALL_X = -1.6  # behind the robot, seen by the front camera
UPRIGHT = [0.7071068, 0, -0.7071068, 0]  # turns SAPIEN's x-aligned cylinders (and joint axes) to z


def render_material(spec: MaterialSpec) -> sapien.render.RenderMaterial:
    """A SAPIEN material from a spec (textures are loaded once per process)."""
    material = sapien.render.RenderMaterial(
        base_color=list(spec.colour), roughness=spec.roughness, metallic=spec.metallic
    )
    if spec.texture is not None:
        material.base_color_texture = load_texture(spec.texture)
    return material


def physical_material(
    friction: float = 1.0, restitution: float = 0.0
) -> sapien.physx.PhysxMaterial:
    return sapien.physx.PhysxMaterial(
        static_friction=friction, dynamic_friction=friction, restitution=restitution
    )


def build_room(scene: ManiSkillScene, spec: EnvironmentSpec) -> Actor:
    """Floor, back wall and the table (returned: tasks place objects on its top)."""
    floor = scene.create_actor_builder()
    floor.add_plane_repeated_visual(
        pose=sapien.Pose(p=[0, 0, -TABLE_HEIGHT]),
        half_size=[4, 4],
        mat=render_material(spec.floor),
        texture_repeat=[2, 2],
    )
    floor.add_plane_collision(sapien.Pose(p=[0, 0, -TABLE_HEIGHT], q=UPRIGHT))
    floor.initial_pose = sapien.Pose()
    floor.build_static(name="floor")

    wall = scene.create_actor_builder()
    wall.add_box_visual(
        pose=sapien.Pose(p=[WALL_X, 0, 0.4]),
        half_size=[0.02, 3.0, 1.6],
        material=render_material(spec.wall),
    )
    wall.initial_pose = sapien.Pose()
    wall.build_static(name="wall")

    table = scene.create_actor_builder()
    top = sapien.Pose(p=[TABLE_CENTER_X, 0, -TABLE_THICKNESS / 2])
    half = [TABLE_HALF_SIZE[0], TABLE_HALF_SIZE[1], TABLE_THICKNESS / 2]
    table.add_box_collision(pose=top, half_size=half, material=physical_material(0.8))
    table.add_box_visual(pose=top, half_size=half, material=render_material(spec.table))
    leg_material = render_material(MaterialSpec(colour=(0.25, 0.22, 0.2, 1.0)))
    leg_h = (TABLE_HEIGHT - TABLE_THICKNESS) / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            p = [
                TABLE_CENTER_X + sx * (TABLE_HALF_SIZE[0] - 0.05),
                sy * (TABLE_HALF_SIZE[1] - 0.05),
                -TABLE_THICKNESS - leg_h,
            ]
            table.add_box_visual(
                pose=sapien.Pose(p=p), half_size=[0.025, 0.025, leg_h], material=leg_material
            )
    table.initial_pose = sapien.Pose()
    return table.build_static(name="table")


def add_lights(scene: ManiSkillScene, spec: EnvironmentSpec, shadows: bool = True) -> None:
    """Ambient + directional lights; only the first casts (directional, cheap) shadows."""
    scene.set_ambient_light(list(spec.ambient))
    for i, light in enumerate(spec.lights):
        cast = shadows and i == 0
        scene.add_directional_light(
            list(light.direction),
            list(light.colour),
            shadow=cast,
            shadow_scale=1.0,
            shadow_map_size=256,
        )


def build_distractor(scene: ManiSkillScene, spec: ObjectSpec, name: str) -> Actor:
    """An unrelated, graspable-looking object standing on the table (dynamic, light)."""
    radius, height = spec.size
    builder = scene.create_actor_builder()
    material = render_material(spec.material)
    centre = sapien.Pose(p=[0, 0, height / 2])
    upright = sapien.Pose(p=[0, 0, height / 2], q=UPRIGHT)
    if spec.shape == "box":
        half = [radius, radius * 0.8, height / 2]
        builder.add_box_collision(pose=centre, half_size=half, density=300)
        builder.add_box_visual(pose=centre, half_size=half, material=material)
    elif spec.shape == "ball":
        ball = sapien.Pose(p=[0, 0, radius])
        builder.add_sphere_collision(pose=ball, radius=radius, density=300)
        builder.add_sphere_visual(pose=ball, radius=radius, material=material)
    elif spec.shape == "capsule":
        half_length = max(height / 2 - radius, 0.005)
        builder.add_capsule_collision(
            pose=upright, radius=radius, half_length=half_length, density=300
        )
        builder.add_capsule_visual(
            pose=upright, radius=radius, half_length=half_length, material=material
        )
    elif spec.shape == "cylinder":
        builder.add_cylinder_collision(
            pose=upright, radius=radius, half_length=height / 2, density=300
        )
        builder.add_cylinder_visual(
            pose=upright, radius=radius, half_length=height / 2, material=material
        )
    else:  # a revolved mesh: vase, bottle, cone, spindle
        scale = [2 * radius, 2 * radius, height]
        path = str(mesh_path(spec.shape))
        builder.add_convex_collision_from_file(path, scale=scale, density=300)
        builder.add_visual_from_file(path, scale=scale, material=material)
    builder.initial_pose = sapien.Pose(p=[0, 0, 0.0])
    return builder.build(name=name)


def rotation_z(angle: float) -> list[float]:
    """A quaternion (wxyz) rotating by `angle` around z."""
    return [float(np.cos(angle / 2)), 0.0, 0.0, float(np.sin(angle / 2))]

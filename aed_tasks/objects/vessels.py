"""Mugs, cups and bowls: revolved visual meshes over convex collision pieces."""

from __future__ import annotations

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from aed_tasks.assets import MESH_PROFILES, mesh_path
from aed_tasks.catalogue import ObjectSpec
from aed_tasks.scene import UPRIGHT, physical_material, render_material


def build_vessel(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, density: float = 450.0
) -> Actor:
    """A mug or cup of `spec.size` = (diameter, height); mugs get a handle along +x.

    The collision is the convex hull of the body (nothing goes inside a mug here), so the
    fingers grip a real rim of the right size; the mass follows from the density.
    """
    diameter, height = spec.size
    builder = scene.create_actor_builder()
    path, scale = str(mesh_path(spec.shape)), [diameter, diameter, height]
    grip = physical_material(1.2)
    builder.add_convex_collision_from_file(path, scale=scale, density=density, material=grip)
    builder.add_visual_from_file(path, scale=scale, material=render_material(spec.material))
    if spec.shape.startswith("mug"):
        half = [0.012, 0.006, height * 0.28]
        handle = sapien.Pose(p=[diameter / 2 + half[0] * 0.8, 0, height * 0.55])
        builder.add_box_collision(pose=handle, half_size=half, density=density, material=grip)
        builder.add_box_visual(pose=handle, half_size=half, material=render_material(spec.material))
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build(name=name)


def frustum_wall(
    r_bottom: float, r_top: float, height: float, z0: float, thickness: float, segments: int
):
    """Poses and half sizes of `segments` boxes forming a conical wall (a bowl's side)."""
    tilt = np.arctan2(r_top - r_bottom, height - z0)
    slant = np.hypot(r_top - r_bottom, height - z0)
    r_mid = (r_bottom + r_top) / 2 + thickness / 2 * np.cos(tilt)
    half = [thickness / 2, np.pi * r_mid / segments * 1.08, slant / 2]
    for k in range(segments):
        yaw = 2 * np.pi * k / segments
        q_yaw = [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
        q_tilt = [np.cos(tilt / 2), 0, np.sin(tilt / 2), 0]  # lean outwards about the tangent (y)
        q = sapien.Pose(q=q_yaw) * sapien.Pose(q=q_tilt)
        p = [r_mid * np.cos(yaw), r_mid * np.sin(yaw), (z0 + height) / 2]
        yield sapien.Pose(p=p, q=q.q), half


def build_bowl(scene: ManiSkillScene, spec: ObjectSpec, name: str, segments: int = 14) -> Actor:
    """A bowl of `spec.size` = (diameter, height): a base disc and a ring of wall boxes."""
    diameter, height = spec.size
    outline = np.asarray(MESH_PROFILES[spec.shape]["outline"])
    floor_z = float(outline[-1, 1]) * height  # inner floor height of the profile
    r_bottom = float(outline[1, 0]) * diameter
    builder = scene.create_actor_builder()
    thickness = 0.006
    builder.add_cylinder_collision(
        pose=sapien.Pose(p=[0, 0, floor_z / 2], q=UPRIGHT),
        radius=r_bottom,
        half_length=floor_z / 2,
        density=600,
    )
    for wall_pose, half in frustum_wall(
        r_bottom, diameter / 2, height, floor_z, thickness, segments
    ):
        builder.add_box_collision(pose=wall_pose, half_size=half, density=600)
    path = str(mesh_path(spec.shape))
    builder.add_visual_from_file(
        path, scale=[diameter, diameter, height], material=render_material(spec.material)
    )
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build(name=name)

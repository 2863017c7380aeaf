"""A glass of water and coasters (Move Glass Cup).

The glass is hollow: a base disc plus rings of wall boxes that follow the outer wall of its
revolved profile, so real contents can slosh in it. The water is a handful of small, light,
slippery spheres ("drops") that rest inside the glass and fly out when it is jerked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from aed_tasks.assets import MESH_PROFILES, mesh_path
from aed_tasks.catalogue import MaterialSpec, ObjectSpec
from aed_tasks.objects.vessels import frustum_wall
from aed_tasks.scene import UPRIGHT, physical_material, render_material

GLASS_WALL = 0.004  # collision wall thickness (m)
GLASS_DENSITY = 2500.0  # soda-lime glass
WATER_DENSITY = 1000.0
WATER_COLOUR = (0.12, 0.42, 0.95, 1.0)
COASTER_DENSITY = 600.0  # cork / wood
GLASS_SEGMENTS = 12  # wall boxes per ring of a round glass


@dataclass(frozen=True)
class GlassGeometry:
    """The glass's outer wall as (radius, z) points in metres, its floor and wall ring."""

    diameter: float
    height: float
    wall: np.ndarray  # (k, 2): outer radius (apothem of the wall ring) at heights z
    floor_z: float
    segments: int  # boxes per wall ring
    visual_yaw: float  # turns a faceted visual mesh so its flats meet the wall boxes

    @property
    def rim_radius(self) -> float:
        return float(self.wall[-1, 0])

    def outer_radius(self, z: np.ndarray | float) -> np.ndarray:
        """Outer wall radius at height z (clamped to the glass)."""
        return np.interp(z, self.wall[:, 1], self.wall[:, 0])

    def inner_radius(self, z: np.ndarray | float) -> np.ndarray:
        return self.outer_radius(z) - GLASS_WALL


def glass_geometry(spec: ObjectSpec) -> GlassGeometry:
    """Read a glass's wall from its mesh profile: the outline's outer side, up to the rim."""
    diameter, height = spec.size[:2]
    profile = MESH_PROFILES[spec.shape]
    outline = np.asarray(profile["outline"], dtype=float)
    top = int(np.argmax(outline[:, 1] >= 1.0))  # first point at the rim: the outer wall ends there
    wall = outline[1 : top + 1] * [diameter, height]
    sections = int(profile["sections"])
    faceted = sections <= GLASS_SEGMENTS
    segments = sections if faceted else GLASS_SEGMENTS
    if faceted:  # the mesh's vertices sit on the outline radius: its flats are closer in
        wall[:, 0] *= np.cos(np.pi / sections)
    return GlassGeometry(
        diameter=diameter,
        height=height,
        wall=wall,
        floor_z=float(outline[-1, 1]) * height,
        segments=segments,
        visual_yaw=np.pi / sections if faceted else 0.0,
    )


def build_glass(scene: ManiSkillScene, spec: ObjectSpec, name: str) -> Actor:
    """A hollow glass of `spec.size` = (diameter, height, drops, drop radius): base + wall rings."""
    geometry = glass_geometry(spec)
    builder = scene.create_actor_builder()
    grip = physical_material(0.6)
    r_base = float(geometry.wall[0, 0])
    builder.add_cylinder_collision(
        pose=sapien.Pose(p=[0, 0, geometry.floor_z / 2], q=UPRIGHT),
        radius=r_base,
        half_length=geometry.floor_z / 2,
        density=GLASS_DENSITY,
        material=grip,
    )
    for (r0, z0), (r1, z1) in zip(geometry.wall[:-1], geometry.wall[1:], strict=True):
        z0 = max(z0, 0.002)  # the boxes' tilted corners must not stick out below the base
        bands = frustum_wall(
            r0 - GLASS_WALL, r1 - GLASS_WALL, z1, z0, GLASS_WALL, geometry.segments
        )
        for pose, half in bands:
            builder.add_box_collision(
                pose=pose, half_size=half, density=GLASS_DENSITY, material=grip
            )
    visual = sapien.Pose(q=[np.cos(geometry.visual_yaw / 2), 0, 0, np.sin(geometry.visual_yaw / 2)])
    builder.add_visual_from_file(
        str(mesh_path(spec.shape)),
        pose=visual,
        scale=[geometry.diameter, geometry.diameter, geometry.height],
        material=glass_material(spec.material),
    )
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build(name=name)


def glass_material(spec: MaterialSpec) -> sapien.render.RenderMaterial:
    """Glossy and pale: the rasterising camera has no refraction, so a light tint reads as glass."""
    material = render_material(spec)
    material.roughness = 0.05
    material.specular = 0.9
    return material


def build_water(scene: ManiSkillScene, spec: ObjectSpec, name: str) -> list[Actor]:
    """The glass's water: `spec.size[2]` light, slippery spheres of radius `spec.size[3]`."""
    count, radius = int(spec.size[2]), float(spec.size[3])
    slippery = physical_material(0.02)
    colour = render_material(MaterialSpec(colour=WATER_COLOUR, roughness=0.1))
    drops = []
    for i in range(count):
        builder = scene.create_actor_builder()
        builder.add_sphere_collision(radius=radius, density=WATER_DENSITY, material=slippery)
        builder.add_visual_from_file(
            str(mesh_path("glass_water_drop")),
            pose=sapien.Pose(p=[0, 0, -radius]),
            scale=[2 * radius, 2 * radius, 2 * radius],
            material=colour,
        )
        builder.initial_pose = sapien.Pose(p=[0, 0, 1.0 + 0.05 * i])
        drops.append(builder.build(name=f"{name}_{i}"))
    return drops


def drop_positions(spec: ObjectSpec, rng: np.random.Generator) -> np.ndarray:
    """Resting spots of the `spec.size[2]` drops in the glass frame, from the floor up."""
    count = int(spec.size[2])
    spots = drop_spots(spec, rng)
    if len(spots) < count:
        raise ValueError(f"{count} drops do not fit in glass {spec.shape} {spec.size}")
    return spots[:count]


def drop_spots(spec: ObjectSpec, rng: np.random.Generator) -> np.ndarray:
    """Every resting spot for a drop of radius `spec.size[3]` below the rim: rings of layers."""
    geometry = glass_geometry(spec)
    radius, gap = float(spec.size[3]), 0.0008
    spots: list[tuple[float, float, float]] = []
    z = geometry.floor_z + radius + gap
    while z + radius <= geometry.height:
        room = (
            float(geometry.inner_radius(z - radius)) - radius - gap
        )  # widest ring that clears the wall
        ring = int(2 * np.pi * room / (2 * radius + gap)) if room > radius else 0
        phase = rng.uniform(0, 2 * np.pi)
        for k in range(ring):
            angle = phase + 2 * np.pi * k / ring
            spots.append((room * np.cos(angle), room * np.sin(angle), z))
        if room >= 2 * radius + gap or ring == 0:
            spots.append((0.0, 0.0, z))
        z += 2 * radius + gap
    return np.asarray(spots).reshape(-1, 3)


def build_coaster(scene: ManiSkillScene, spec: ObjectSpec, name: str) -> Actor:
    """A thin coaster of `spec.size` = (diameter, thickness), its top at z = thickness."""
    diameter, thickness = spec.size
    builder = scene.create_actor_builder()
    material, friction = render_material(spec.material), physical_material(0.9)
    centre = sapien.Pose(p=[0, 0, thickness / 2])
    if spec.shape.startswith("coaster_round"):
        upright = sapien.Pose(p=[0, 0, thickness / 2], q=UPRIGHT)
        builder.add_cylinder_collision(
            pose=upright,
            radius=diameter / 2,
            half_length=thickness / 2,
            density=COASTER_DENSITY,
            material=friction,
        )
        builder.add_cylinder_visual(
            pose=upright, radius=diameter / 2, half_length=thickness / 2, material=material
        )
    elif spec.shape.startswith("coaster_square"):
        half = [diameter / 2, diameter / 2, thickness / 2]
        builder.add_box_collision(
            pose=centre, half_size=half, density=COASTER_DENSITY, material=friction
        )
        builder.add_box_visual(pose=centre, half_size=half, material=material)
    else:  # a prism from a revolved mesh: hexagon, oval (squashed along y)
        squash = 0.78 if spec.shape.startswith("coaster_oval") else 1.0
        path, scale = (
            str(mesh_path(coaster_mesh(spec.shape))),
            [diameter, diameter * squash, thickness],
        )
        builder.add_convex_collision_from_file(
            path, scale=scale, density=COASTER_DENSITY, material=friction
        )
        builder.add_visual_from_file(path, scale=scale, material=material)
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build(name=name)


def coaster_mesh(shape: str) -> str:
    """The mesh of a mesh-built coaster shape (shape names may carry a split suffix)."""
    return "coaster_hexagon" if shape.startswith("coaster_hexagon") else "coaster_oval"


def coaster_support_radius(spec: ObjectSpec) -> float:
    """Radius of the largest disc the coaster's top covers, around its centre."""
    diameter = spec.size[0]
    if spec.shape.startswith("coaster_hexagon"):
        return diameter / 2 * np.cos(np.pi / 6)
    if spec.shape.startswith("coaster_oval"):
        return diameter / 2 * 0.78
    return diameter / 2

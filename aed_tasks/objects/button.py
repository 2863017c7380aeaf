"""Push buttons: a fixed housing and a spring-loaded cap on a prismatic joint along z.

The cap is an articulation link whose joint runs from 0 (rest, up) to -travel (fully
down). A PD drive aimed a little above the upper limit acts as a preloaded spring, so the
cap rests against its upper limit and pops back up when released. Shapes differ by split:
base buttons have flat round caps (disc, mushroom) on a block or a puck; novel ones have a
square or a domed cap on a hexagonal or a stepped housing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Articulation

from aed_tasks.assets import mesh_path
from aed_tasks.catalogue import ObjectSpec
from aed_tasks.scene import UPRIGHT, render_material

CAP_CLEARANCE = 0.001  # gap left between the cap and the housing at full travel
SPRING_PRELOAD = 0.008  # drive target above the upper limit (m): the cap rests firmly up
HOUSING_DENSITY, CAP_DENSITY = 800.0, 500.0

HOUSING_SHAPES = {
    "base": ("button_housing_block", "button_housing_puck"),
    "novel": ("button_housing_hex", "button_housing_plinth"),
}
CAP_SHAPES = {
    "base": ("button_cap_disc", "button_cap_mushroom"),
    "novel": ("button_cap_square", "button_cap_dome"),
}


@dataclass(frozen=True)
class ButtonGeometry:
    """Dimensions of a button, read from its housing and cap specs.

    housing spec size: (half width, height); cap spec size: (half width, height, travel,
    spring stiffness in N/m).
    """

    housing_half: float
    housing_height: float
    cap_half: float
    cap_height: float
    travel: float
    stiffness: float

    @classmethod
    def from_specs(cls, housing: ObjectSpec, cap: ObjectSpec) -> ButtonGeometry:
        housing_half, housing_height = housing.size
        cap_half, cap_height, travel, stiffness = cap.size
        return cls(housing_half, housing_height, cap_half, cap_height, travel, stiffness)

    @property
    def cap_bottom(self) -> float:
        """Height of the cap's underside above the housing top, at rest (in the cap's frame)."""
        return self.travel + CAP_CLEARANCE

    @property
    def cap_top(self) -> float:
        """Height of the cap's top above the table, at rest."""
        return self.housing_height + self.cap_bottom + self.cap_height

    @property
    def footprint(self) -> float:
        """Radius of a circle holding the whole housing, whatever its shape and yaw."""
        return self.housing_half * np.sqrt(2)


def _add_cylinder(
    builder, radius: float, z0: float, z1: float, material, density: float, collide: bool = True
) -> None:
    pose = sapien.Pose(p=[0, 0, (z0 + z1) / 2], q=UPRIGHT)
    if collide:
        builder.add_cylinder_collision(
            pose=pose, radius=radius, half_length=(z1 - z0) / 2, density=density
        )
    builder.add_cylinder_visual(
        pose=pose, radius=radius, half_length=(z1 - z0) / 2, material=material
    )


def _add_box(
    builder, half_xy: float, z0: float, z1: float, material, density: float, collide: bool = True
) -> None:
    pose, half = sapien.Pose(p=[0, 0, (z0 + z1) / 2]), [half_xy, half_xy, (z1 - z0) / 2]
    if collide:
        builder.add_box_collision(pose=pose, half_size=half, density=density)
    builder.add_box_visual(pose=pose, half_size=half, material=material)


def _add_prism(
    builder, shape: str, half: float, z0: float, z1: float, material, density: float
) -> None:
    """A convex solid from a generated mesh of unit height (hexagonal prism, dome)."""
    path, scale = str(mesh_path(shape)), [2 * half, 2 * half, z1 - z0]
    pose = sapien.Pose(p=[0, 0, z0])
    builder.add_convex_collision_from_file(path, pose=pose, scale=scale, density=density)
    builder.add_visual_from_file(path, pose=pose, scale=scale, material=material)


def _build_housing(builder, spec: ObjectSpec, g: ButtonGeometry) -> None:
    material = render_material(spec.material)
    h, r = g.housing_height, g.housing_half
    if spec.shape == "button_housing_block":
        _add_box(builder, r, 0.0, h, material, HOUSING_DENSITY)
    elif spec.shape == "button_housing_puck":
        _add_cylinder(builder, r, 0.0, h, material, HOUSING_DENSITY)
    elif spec.shape == "button_housing_hex":
        _add_prism(builder, spec.shape, r, 0.0, h, material, HOUSING_DENSITY)
    elif spec.shape == "button_housing_plinth":  # a wide thin plate under a narrower block
        _add_box(builder, r, 0.0, h * 0.35, material, HOUSING_DENSITY)
        _add_box(builder, max(r * 0.72, g.cap_half * 1.25), h * 0.35, h, material, HOUSING_DENSITY)
    else:
        raise ValueError(f"unknown button housing {spec.shape!r}")


def _build_cap(builder, spec: ObjectSpec, housing_material, g: ButtonGeometry) -> None:
    """Cap geometry in the cap link's frame, whose origin sits on the housing top at rest."""
    material = render_material(spec.material)
    z0, z1, r = g.cap_bottom, g.cap_bottom + g.cap_height, g.cap_half
    # a stem down into the housing (visual only): the cap never looks like it floats
    _add_cylinder(
        builder, r * 0.55, -0.004, z0 + 0.001, housing_material, CAP_DENSITY, collide=False
    )
    if spec.shape == "button_cap_disc":
        _add_cylinder(builder, r, z0, z1, material, CAP_DENSITY)
    elif spec.shape == "button_cap_mushroom":  # a narrow neck under a wide, thin head
        neck = z0 + g.cap_height * 0.45
        _add_cylinder(builder, r * 0.7, z0, neck, material, CAP_DENSITY)
        _add_cylinder(builder, r, neck, z1, material, CAP_DENSITY)
    elif spec.shape == "button_cap_square":
        _add_box(builder, r * 0.9, z0, z1, material, CAP_DENSITY)
    elif spec.shape == "button_cap_dome":  # a revolved dome, its crown at the centre
        _add_prism(builder, spec.shape, r, z0, z1, material, CAP_DENSITY)
    else:
        raise ValueError(f"unknown button cap {spec.shape!r}")


def build_button(
    scene: ManiSkillScene, housing: ObjectSpec, cap: ObjectSpec, name: str
) -> Articulation:
    """A fixed push button; its single active joint is the cap's prismatic joint (qpos <= 0).

    Its return spring (`set_button_spring`) is set here and lasts: drives are joint properties.
    """
    g = ButtonGeometry.from_specs(housing, cap)
    builder = scene.create_articulation_builder()
    base = builder.create_link_builder(parent=None)
    base.set_name("button_housing")
    _build_housing(base, housing, g)
    link = builder.create_link_builder(parent=base)
    link.set_name("button_cap")
    _build_cap(link, cap, render_material(housing.material), g)
    link.set_joint_name("cap_joint")
    link.set_joint_properties(
        "prismatic",
        limits=[[-g.travel, 0.0]],
        pose_in_parent=sapien.Pose(p=[0, 0, g.housing_height], q=UPRIGHT),
        pose_in_child=sapien.Pose(q=UPRIGHT),
        friction=0.0,
        damping=0.0,
    )
    builder.initial_pose = sapien.Pose(p=[0.0, 0.0, 0.0])
    button = builder.build(name=name, fix_root_link=True)
    set_button_spring(button, g)
    return button


def set_button_spring(button: Articulation, g: ButtonGeometry) -> None:
    """The return spring: a stiff PD drive aimed just above the cap's upper limit."""
    joint = button.active_joints[0]
    damping = 2.0 * np.sqrt(g.stiffness * 0.03)  # about critical for a cap of some 30 g
    joint.set_drive_properties(stiffness=g.stiffness, damping=float(damping))
    joint.set_drive_target([SPRING_PRELOAD])

"""Drawer units: a fixed cabinet (root link) and a drawer sliding on a prismatic joint.

The unit's frame has its origin at the cabinet's front bottom edge, centred in y, on the
table; the cabinet extends along +x and its opening faces -x (the robot). The joint value
is how far the drawer is pulled out (0 = fully closed, against the joint's lower limit).
Both links are compounds of boxes (and cylinders or balls for knobs): a hollow cabinet and an
open tray, so that the drawer really slides inside the cabinet.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Articulation
from sapien.physx import PhysxMaterial
from sapien.render import RenderMaterial
from sapien.wrapper.articulation_builder import LinkBuilder

from aed_tasks.catalogue import MaterialSpec, ObjectSpec
from aed_tasks.scene import physical_material, render_material

# Designs, disjoint by split: cabinets (shell, plinth, legs, crown) and drawers (by handle).
CABINET_SHAPES = {
    "base": ("cabinet_plain", "cabinet_plinth"),
    "novel": ("cabinet_legged", "cabinet_crowned"),
}
DRAWER_SHAPES = {
    "base": ("drawer_bar", "drawer_knob", "drawer_ledge"),
    "novel": ("drawer_twin_balls", "drawer_vertical_bar", "drawer_block"),
}
CABINET_LIFT = {
    "cabinet_plain": 0.0,
    "cabinet_plinth": 0.018,
    "cabinet_legged": 0.03,
    "cabinet_crowned": 0.0,
}

WALL = 0.01  # cabinet wall thickness
TRAY_WALL = 0.006
PANEL_THICKNESS = 0.014
CLEARANCE = 0.003  # between the drawer and the cabinet (no rubbing contact)
PANEL_GAP = 0.002  # between the closed panel and the cabinet front (the joint limit stops it)
DRAWER_DENSITY = 550.0  # wood-like: a drawer of ~0.3 kg
JOINT_DAMPING = 8.0  # N s / m: the drawer stops soon after it is let go
JOINT_FRICTION = 0.05
ROTATE_Z_180 = [0.0, 0.0, 0.0, 1.0]  # joint frame turned so that a positive value pulls toward -x


@dataclass(frozen=True)
class DrawerLayout:
    """What the expert needs to push a built unit, in the unit's frame (metres)."""

    width: float
    depth: float
    panel_front_x: float  # x of the panel's front face when closed (negative: before the cabinet)
    panel_bottom_z: float
    panel_top_z: float
    handle_reach: float  # how far the handle stands out of the panel (-x)
    unit_top_z: float  # highest point of the cabinet
    travel: float  # upper joint limit


def drawer_layout(cabinet: ObjectSpec, drawer: ObjectSpec) -> DrawerLayout:
    """The geometry of a unit built from `cabinet` (width, depth, height) and `drawer`."""
    width, depth, height = cabinet.size
    lift = CABINET_LIFT[cabinet.shape]
    front_x = (
        -0.012 if cabinet.shape == "cabinet_crowned" else 0.0
    )  # the crowned cabinet has a face frame
    top = lift + height + (0.008 if cabinet.shape in ("cabinet_crowned", "cabinet_plinth") else 0.0)
    return DrawerLayout(
        width=width,
        depth=depth,
        panel_front_x=front_x - PANEL_GAP - PANEL_THICKNESS,
        panel_bottom_z=lift + CLEARANCE,
        panel_top_z=lift + height - CLEARANCE,
        handle_reach=drawer.size[1],
        unit_top_z=top,
        travel=depth - 0.04,
    )


def _box(
    link: LinkBuilder,
    centre,
    half,
    material: RenderMaterial,
    physical: PhysxMaterial,
    density: float,
) -> None:
    """One box, seen and solid."""
    pose = sapien.Pose(p=[float(v) for v in centre])
    half = [float(v) for v in half]
    link.add_box_collision(pose=pose, half_size=half, material=physical, density=density)
    link.add_box_visual(pose=pose, half_size=half, material=material)


def _shade(
    spec: MaterialSpec, factor: float, roughness: float = 0.8, metallic: float = 0.0
) -> RenderMaterial:
    """A darker (factor < 1) plain version of a material: trims, legs, handles."""
    colour = tuple(factor * c for c in spec.colour[:3]) + (1.0,)
    return render_material(MaterialSpec(colour=colour, roughness=roughness, metallic=metallic))


def _span(lo: float, hi: float) -> tuple[float, float]:
    """Centre and half extent of the interval [lo, hi]."""
    return (lo + hi) / 2, (hi - lo) / 2


def _add_cabinet(link: LinkBuilder, spec: ObjectSpec, material: RenderMaterial) -> None:
    """The hollow cabinet: bottom, top, sides, back (+ its design's plinth, legs or crown)."""
    width, depth, height = spec.size
    lift = CABINET_LIFT[spec.shape]
    physical = physical_material(0.6)
    hw, z0, z1 = width / 2, lift, lift + height
    cx, hx = _span(0.0, depth)
    for z_lo, z_hi in ((z0, z0 + WALL), (z1 - WALL, z1)):  # bottom and top plates
        cz, hz = _span(z_lo, z_hi)
        _box(link, [cx, 0, cz], [hx, hw, hz], material, physical, 500)
    cz, hz = _span(z0 + WALL, z1 - WALL)
    for side in (-1, 1):
        cy, hy = _span(hw - WALL, hw)
        _box(link, [cx, side * cy, cz], [hx, hy, hz], material, physical, 500)
    bx, bhx = _span(depth - WALL, depth)
    _box(link, [bx, 0, cz], [bhx, hw - WALL, hz], material, physical, 500)

    dark = _shade(spec.material, 0.35)
    if spec.shape == "cabinet_plinth":  # recessed plinth and a thin overhanging top
        _box(link, [cx + 0.01, 0, lift / 2], [hx - 0.02, hw - 0.015, lift / 2], dark, physical, 500)
        _box(
            link,
            [cx - 0.005, 0, z1 + 0.004],
            [hx + 0.005, hw + 0.006, 0.004],
            material,
            physical,
            500,
        )
    elif spec.shape == "cabinet_legged":  # four square legs
        for sx in (0.02, depth - 0.02):
            for sy in (-1, 1):
                _box(
                    link,
                    [sx, sy * (hw - 0.02), lift / 2],
                    [0.012, 0.012, lift / 2],
                    dark,
                    physical,
                    500,
                )
    elif spec.shape == "cabinet_crowned":  # a face frame around the opening and a crown
        fx, fhx = _span(-0.012, 0.0)
        _box(link, [fx, 0, z0 + WALL / 2], [fhx, hw, WALL / 2], dark, physical, 500)
        _box(link, [fx, 0, z1 - WALL / 2], [fhx, hw, WALL / 2], dark, physical, 500)
        for side in (-1, 1):
            _box(link, [fx, side * (hw - WALL / 2), cz], [fhx, WALL / 2, hz], dark, physical, 500)
        _box(
            link, [cx - 0.008, 0, z1 + 0.004], [hx + 0.008, hw + 0.004, 0.004], dark, physical, 500
        )


def _add_tray(
    link: LinkBuilder,
    cabinet: ObjectSpec,
    layout: DrawerLayout,
    front: RenderMaterial,
    inner: RenderMaterial,
) -> None:
    """The drawer at joint value 0: an open tray inside the cabinet behind a front panel."""
    width, depth, height = cabinet.size
    lift = CABINET_LIFT[cabinet.shape]
    physical = physical_material(0.5)
    density = DRAWER_DENSITY
    panel_back = layout.panel_front_x + PANEL_THICKNESS
    x_lo, x_hi = panel_back, depth - WALL - CLEARANCE
    hy = width / 2 - WALL - CLEARANCE  # half width of the tray
    z_lo = lift + WALL + CLEARANCE
    z_hi = lift + height - WALL - CLEARANCE - 0.01  # tray sides stay below the cabinet's top
    cx, hx = _span(x_lo, x_hi)
    bz, bhz = _span(z_lo, z_lo + TRAY_WALL)
    _box(link, [cx, 0, bz], [hx, hy, bhz], inner, physical, density)
    sz, shz = _span(z_lo + TRAY_WALL, z_hi)
    for side in (-1, 1):
        cy, hcy = _span(hy - TRAY_WALL, hy)
        _box(link, [cx, side * cy, sz], [hx, hcy, shz], inner, physical, density)
    rx, rhx = _span(x_hi - TRAY_WALL, x_hi)
    _box(link, [rx, 0, sz], [rhx, hy - TRAY_WALL, shz], inner, physical, density)
    px, phx = _span(layout.panel_front_x, panel_back)
    pz, phz = _span(layout.panel_bottom_z, layout.panel_top_z)
    _box(link, [px, 0, pz], [phx, width / 2 - CLEARANCE, phz], front, physical, density)


def _add_handle(link: LinkBuilder, spec: ObjectSpec, layout: DrawerLayout) -> None:
    """The drawer design's handle on the panel's front face, below where the gripper pushes."""
    length, reach = spec.size
    material = _shade(
        spec.material, 0.45, roughness=0.3, metallic=0.7
    )  # a metallic shade of the front
    physical = physical_material(0.6)
    x_face = layout.panel_front_x
    z = layout.panel_bottom_z + 0.4 * (layout.panel_top_z - layout.panel_bottom_z)
    out_x, out_hx = _span(x_face - reach, x_face)
    grip_x, grip_hx = _span(x_face - reach, x_face - reach + 0.01)
    post = [out_hx, 0.005, 0.005]
    if spec.shape == "drawer_bar":
        for side in (-1, 1):
            _box(link, [out_x, side * length / 2, z], post, material, physical, 2000)
        _box(link, [grip_x, 0, z], [grip_hx, length / 2 + 0.008, 0.006], material, physical, 2000)
    elif spec.shape == "drawer_vertical_bar":
        for side in (-1, 1):
            _box(link, [out_x, 0, z + side * 0.016], post, material, physical, 2000)
        _box(link, [grip_x, 0, z], [grip_hx, 0.006, 0.024], material, physical, 2000)
    elif spec.shape == "drawer_ledge":
        _box(link, [out_x, 0, z], [out_hx, length / 2, 0.004], material, physical, 2000)
    elif spec.shape == "drawer_block":
        _box(link, [out_x, 0, z], [out_hx, length / 4, 0.011], material, physical, 2000)
    elif spec.shape == "drawer_twin_balls":  # two balls on thin square stems
        ball = 0.012
        stem_x, stem_hx = _span(x_face - reach + ball, x_face)
        for y in (-length / 2, length / 2):
            _box(link, [stem_x, y, z], [stem_hx, 0.004, 0.004], material, physical, 2000)
            pose = sapien.Pose(p=[x_face - reach + ball, y, z])
            link.add_sphere_collision(pose=pose, radius=ball, material=physical, density=2000)
            link.add_sphere_visual(pose=pose, radius=ball, material=material)
    elif spec.shape == "drawer_knob":  # a cylinder along x (SAPIEN's axis): out of the panel
        pose = sapien.Pose(p=[out_x, 0, z])
        link.add_cylinder_collision(
            pose=pose, radius=0.011, half_length=out_hx, material=physical, density=2000
        )
        link.add_cylinder_visual(pose=pose, radius=0.011, half_length=out_hx, material=material)
    else:
        raise ValueError(f"unknown drawer design {spec.shape!r}; known: {DRAWER_SHAPES}")


def build_drawer_unit(
    scene: ManiSkillScene, cabinet: ObjectSpec, drawer_spec: ObjectSpec, name: str
) -> tuple[Articulation, DrawerLayout]:
    """A cabinet (fixed root) with one drawer on a damped prismatic joint.

    `cabinet.size` = (width, depth, height); `drawer_spec.shape` names the handle design,
    `drawer_spec.size` = (handle length, handle reach), its material colours the front panel.
    """
    layout = drawer_layout(cabinet, drawer_spec)
    builder = scene.create_articulation_builder()
    body = builder.create_link_builder()
    body.set_name("cabinet")
    _add_cabinet(body, cabinet, render_material(cabinet.material))

    drawer = builder.create_link_builder(body)
    drawer.set_name("drawer")
    inner_colour = tuple(0.8 * c for c in cabinet.material.colour[:3]) + (
        1.0,
    )  # the tray: a darker cabinet
    inner = render_material(replace(cabinet.material, colour=inner_colour))
    _add_tray(drawer, cabinet, layout, render_material(drawer_spec.material), inner)
    _add_handle(drawer, drawer_spec, layout)
    drawer.set_joint_name("slide")
    drawer.set_joint_properties(
        type="prismatic",
        limits=[[0.0, layout.travel]],
        pose_in_parent=sapien.Pose(q=ROTATE_Z_180),
        pose_in_child=sapien.Pose(q=ROTATE_Z_180),
        friction=JOINT_FRICTION,
        damping=JOINT_DAMPING,
    )
    builder.initial_pose = sapien.Pose(p=[0.0, 0.0, 0.0])
    unit = builder.build(name=name, fix_root_link=True)
    for joint in unit.get_active_joints():
        joint.set_friction(JOINT_FRICTION)  # ManiSkill's builder sets the damping, not the friction
    return unit, layout

"""Bookshelves (desk hutches) with free space under their lowest board, and the items pushed under.

A shelf is a compound of boxes (and cylinders) standing on the table. In its own frame the
origin lies on the table top at the centre of its footprint; the free space under the
lowest board (`shelf_opening`) opens towards -x, the robot's side, and stays open at the
back (so the front camera sees through it). Designs are split-specific (`SHELF_SHAPES`),
so base and novel shelves never share a shape name. Shelf `ObjectSpec.size` = (outer
width along y, depth along x, clearance height of the free space); `sample_shelf_size`
draws sizes the Panda can push things under.

Why these sizes: with the top-down gripper the fingertips can never cross the mouth
before the arm does. When the TCP is 2 cm over the table, the hand (0.21 m wide along y)
leads it by 3 cm along x and the wrist (link 6) by 4.3 cm, reaching up to z = 0.31 m.
(A higher board is no way out: at the rest pose the wrist stands between the shelves
at about 0.38 m.)
To push something *fully* under, hand and wrist must pass under the board: the clearance
is at least `MIN_CLEARANCE` and the free width at least `MIN_FREE_WIDTH`. The forearm
(link 5) swings up to 0.15 m beside the TCP, at the TCP's x: the side supports stand
`SETBACK` behind the mouth, under an overhanging board.

The items (`ITEM_SHAPES`) are small graspable blocks, books, canisters and loaves whose
width along y fits the Panda's open fingers. Item `ObjectSpec.size` = (length along x,
width along y, height); `item_corners` gives the world corners of an item's bounding box,
which is how "fully under the shelf" is decided.
"""

from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from aed_tasks.catalogue import MaterialSpec, ObjectSpec
from aed_tasks.scene import UPRIGHT, physical_material, render_material

SHELF_SHAPES: dict[str, tuple[str, ...]] = {
    "base": ("shelf_slab", "shelf_ledge"),
    "novel": ("shelf_posts", "shelf_columns"),
}
ITEM_SHAPES: dict[str, tuple[str, ...]] = {
    "base": ("item_block", "item_book"),
    "novel": ("item_canister", "item_loaf"),
}
BOARD = 0.018  # thickness of the boards under which things are pushed
SIDE = 0.018  # thickness of side boards, and the side of square posts
SHELF_DENSITY = 600.0
ITEM_DENSITY = 500.0
MIN_CLEARANCE = 0.335  # the wrist reaches z = 0.31 m while the fingertips push 1 cm over the table
MIN_FREE_WIDTH = 0.235  # the hand is 0.21 m wide along y (plus a little lateral slack)
# the supports stand this far behind the mouth: the forearm, up to 7 cm ahead of the TCP and
# 13 cm beside it, hit front posts only 3 cm behind it
SETBACK = 0.06


def sample_shelf_size(rng: np.random.Generator) -> tuple[float, float, float]:
    """(outer width, depth, clearance) of a shelf the Panda can push an item fully under."""
    width = rng.uniform(MIN_FREE_WIDTH + 2 * SIDE + 0.01, MIN_FREE_WIDTH + 2 * SIDE + 0.04)
    return (
        float(width),
        float(rng.uniform(0.13, 0.16)),
        float(rng.uniform(MIN_CLEARANCE, MIN_CLEARANCE + 0.025)),
    )


def shelf_opening(spec: ObjectSpec) -> tuple[float, float, float]:
    """The free space under the shelf's lowest board, in the shelf frame.

    Returns (half_width, half_depth, clearance): the space spans |y| <= half_width,
    |x| <= half_depth, 0 <= z <= clearance. Its mouth is the plane x = -half_depth.
    """
    width, depth, clearance = spec.size
    return width / 2 - SIDE, depth / 2, clearance


def shelf_height(spec: ObjectSpec) -> float:
    """Height of the top of the lowest board (decorations on top are not counted)."""
    return spec.size[2] + BOARD


def build_shelf(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, kinematic: bool = True
) -> Actor:
    """A low bookshelf of `spec.shape` (see `SHELF_SHAPES`); books stand on it as decoration.

    Kinematic by default, so that `set_pose` can move it between episodes; nothing the
    robot does moves it. Pass `kinematic=False` for a static shelf that never moves.
    """
    if spec.shape not in _DESIGNS:
        raise ValueError(f"unknown shelf shape {spec.shape!r}; known: {sorted(_DESIGNS)}")
    builder = scene.create_actor_builder()
    material = render_material(spec.material)
    for pose, half, collide in _DESIGNS[spec.shape](spec):
        if collide:
            builder.add_box_collision(
                pose=pose, half_size=half, density=SHELF_DENSITY, material=physical_material(0.6)
            )
        builder.add_box_visual(pose=pose, half_size=half, material=material)
    if spec.shape == "shelf_columns":
        _add_columns(builder, spec, material)
    _add_books(builder, spec)
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build_kinematic(name=name) if kinematic else builder.build_static(name=name)


Box = tuple[sapien.Pose, list[float], bool]  # pose, half size, has collision


def _top_board(spec: ObjectSpec) -> Box:
    width, depth, clearance = spec.size
    half = [depth / 2, width / 2, BOARD / 2]
    return sapien.Pose(p=[0, 0, clearance + BOARD / 2]), half, True


def _side_boards(spec: ObjectSpec) -> list[Box]:
    width, depth, clearance = spec.size
    half = [(depth - SETBACK) / 2, SIDE / 2, clearance / 2]
    return [
        (sapien.Pose(p=[SETBACK / 2, s * (width / 2 - SIDE / 2), clearance / 2]), half, True)
        for s in (-1, 1)
    ]


def _post_positions(spec: ObjectSpec, inset: float) -> list[tuple[float, float]]:
    """(x, y) of four posts of side `2 * inset`: the front pair set back from the mouth."""
    width, depth, _ = spec.size
    xs = (-depth / 2 + SETBACK + inset, depth / 2 - inset)
    return [(x, sy * (width / 2 - inset)) for x in xs for sy in (-1, 1)]


def _slab(spec: ObjectSpec) -> list[Box]:
    """Two side boards under one top board."""
    return [*_side_boards(spec), _top_board(spec)]


def _ledge(spec: ObjectSpec) -> list[Box]:
    """Side boards, a top board and a low ledge along its back edge."""
    width, depth, clearance = spec.size
    ledge = sapien.Pose(p=[depth / 2 - SIDE / 2, 0, clearance + BOARD + 0.02])
    return [*_side_boards(spec), _top_board(spec), (ledge, [SIDE / 2, width / 2, 0.02], True)]


def _posts(spec: ObjectSpec) -> list[Box]:
    """Four square posts under a top board with a back rail."""
    width, depth, clearance = spec.size
    posts = [
        (sapien.Pose(p=[x, y, clearance / 2]), [SIDE / 2, SIDE / 2, clearance / 2], True)
        for x, y in _post_positions(spec, SIDE / 2)
    ]
    rail = sapien.Pose(p=[depth / 2 - 0.006, 0, clearance + BOARD + 0.035])
    return [*posts, _top_board(spec), (rail, [0.006, width / 2, 0.035], True)]


def _columns(spec: ObjectSpec) -> list[Box]:
    """Round columns (added by `_add_columns`) under a top board with a crown moulding."""
    width, depth, clearance = spec.size
    crown = sapien.Pose(p=[0, 0, clearance + BOARD + 0.006])
    return [_top_board(spec), (crown, [depth / 2 - 0.012, width / 2 - 0.012, 0.006], False)]


_DESIGNS = {
    "shelf_slab": _slab,
    "shelf_ledge": _ledge,
    "shelf_posts": _posts,
    "shelf_columns": _columns,
}


def _add_columns(
    builder: sapien.ActorBuilder, spec: ObjectSpec, material: sapien.render.RenderMaterial
) -> None:
    clearance = spec.size[2]
    for x, y in _post_positions(spec, SIDE / 2):
        pose = sapien.Pose(p=[x, y, clearance / 2], q=UPRIGHT)
        builder.add_cylinder_collision(
            pose=pose, radius=SIDE / 2, half_length=clearance / 2, density=SHELF_DENSITY
        )
        builder.add_cylinder_visual(
            pose=pose, radius=SIDE / 2, half_length=clearance / 2, material=material
        )


def _add_books(builder: sapien.ActorBuilder, spec: ObjectSpec) -> None:
    """A row of books standing at the back of the top (visual only: nothing touches them)."""
    width, depth, clearance = spec.size
    base = np.asarray(spec.material.colour[:3])
    x_back = (
        depth / 2 - 0.045 if spec.shape in ("shelf_ledge", "shelf_posts") else depth / 2 - 0.035
    )
    y = -width / 2 + 0.04
    for k, (thick, tall, shade) in enumerate(
        ((0.022, 0.07, 0.55), (0.016, 0.06, 1.35), (0.026, 0.075, 0.8), (0.018, 0.055, 0.4))
    ):
        if y + thick > width / 2 - 0.03:
            break
        colour = tuple(float(v) for v in np.clip(base * shade + (0.15 if k % 2 else 0.0), 0, 1)) + (
            1.0,
        )
        half = [0.03, thick / 2, tall / 2]
        pose = sapien.Pose(p=[x_back, y + thick / 2, clearance + BOARD + tall / 2])
        builder.add_box_visual(
            pose=pose,
            half_size=half,
            material=render_material(MaterialSpec(colour=colour, roughness=0.8)),
        )
        y += thick + 0.004


# --- items ----------------------------------------------------------------------------------
PAGES = MaterialSpec(colour=(0.93, 0.91, 0.84, 1.0), roughness=0.9)


def build_item(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, density: float = ITEM_DENSITY
) -> Actor:
    """A graspable item of `spec.size` = (length x, width y, height), origin at its bottom centre.

    Blocks, books and cases collide as one or two boxes, canisters as a cylinder lying along
    x; the fingers (closing along y) grip its flat or round sides by friction.
    """
    length, width, height = spec.size
    builder = scene.create_actor_builder()
    material = render_material(spec.material)
    grip = physical_material(1.0)
    centre = sapien.Pose(p=[0, 0, height / 2])
    half = [length / 2, width / 2, height / 2]
    if spec.shape == "item_canister":  # lying along x: a drum with a darker lid at each end
        _add_octagonal_drum(builder, length, height / 2, density, grip)
        builder.add_cylinder_visual(
            pose=centre, radius=height / 2, half_length=length / 2 - 0.003, material=material
        )
        lids = render_material(
            MaterialSpec(colour=(0.6, 0.6, 0.62, 1.0), roughness=0.3, metallic=0.8)
        )
        for s in (-1, 1):
            lid = sapien.Pose(p=[s * (length / 2 - 0.0015), 0, height / 2])
            builder.add_cylinder_visual(
                pose=lid, radius=height / 2 * 0.97, half_length=0.0015, material=lids
            )
    elif spec.shape == "item_loaf":  # a box under a round roof (a half drum along x)
        roof = width / 2
        body = sapien.Pose(p=[0, 0, (height - roof) / 2])
        body_half = [length / 2, width / 2, (height - roof) / 2]
        builder.add_box_collision(pose=body, half_size=body_half, density=density, material=grip)
        builder.add_box_visual(pose=body, half_size=body_half, material=material)
        top = sapien.Pose(p=[0, 0, height - roof])  # SAPIEN cylinders lie along x
        builder.add_cylinder_collision(
            pose=top, radius=roof, half_length=length / 2, density=density, material=grip
        )
        builder.add_cylinder_visual(
            pose=top, radius=roof, half_length=length / 2, material=material
        )
    else:
        builder.add_box_collision(pose=centre, half_size=half, density=density, material=grip)
        if spec.shape == "item_book":  # covers and spine in colour, pages showing on three sides
            cover = 0.003
            for z in (cover / 2, height - cover / 2):
                builder.add_box_visual(
                    pose=sapien.Pose(p=[0, 0, z]),
                    half_size=[half[0], half[1], cover / 2],
                    material=material,
                )
            spine = sapien.Pose(p=[0, -half[1] + cover / 2, height / 2])
            builder.add_box_visual(
                pose=spine, half_size=[half[0], cover / 2, half[2]], material=material
            )
            pages = sapien.Pose(p=[-0.001, cover / 2 - 0.001, height / 2])
            builder.add_box_visual(
                pose=pages,
                half_size=[half[0] - 0.001, half[1] - cover / 2, half[2] - cover],
                material=render_material(PAGES),
            )
        else:
            builder.add_box_visual(pose=centre, half_size=half, material=material)
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build(name=name)


def _add_octagonal_drum(
    builder: sapien.ActorBuilder, length: float, radius: float, density: float, material
) -> None:
    """The canister's collision: four boxes turned 45 degrees apart about x, flat faces at `radius`.

    A lying PhysX cylinder rolls away on its own from any small tilt (it even gains speed):
    the canister, released or nudged, left its lane in about half of the episodes. The
    octagon-like section rests on a flat face (1.7 cm wide) and must tip 22.5 degrees to
    roll; the fingers grip its flat sides at y = +-radius and push its flat end.
    """
    half_flat = radius * np.tan(np.pi / 8)
    # the boxes overlap: scale the density so the mass is the round drum's
    density = density * np.pi * radius**2 / (4 * 4 * radius * half_flat)
    for k in range(4):
        angle = k * np.pi / 4
        pose = sapien.Pose(p=[0, 0, radius], q=[np.cos(angle / 2), np.sin(angle / 2), 0, 0])
        builder.add_box_collision(
            pose=pose, half_size=[length / 2, radius, half_flat], density=density, material=material
        )


_UNIT_CORNERS = (
    torch.tensor(
        [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (0, 2)], dtype=torch.float32
    )
    / 2
)


def item_corners(item: Actor, spec: ObjectSpec) -> torch.Tensor:
    """World positions (n, 8, 3) of the corners of the item's bounding box."""
    length, width, height = spec.size
    local = _UNIT_CORNERS.to(item.pose.p.device) * torch.tensor(
        [length, width, height], device=item.pose.p.device
    )
    rot = item.pose.to_transformation_matrix()[:, :3, :3]
    return item.pose.p[:, None, :] + local[None] @ rot.transpose(1, 2)

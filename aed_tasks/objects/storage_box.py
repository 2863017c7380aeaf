"""Back to Box objects: toy cubes (magic cube, die), open storage boxes and a low bookshelf.

The toy cube is one box whose faces carry a generated atlas texture (stickers, pips or
numerals): a single render shape, so it costs no more to draw than a plain box. The
storage box is a light dynamic compound (bottom + four walls). The bookshelf is a
kinematic compound with free space below its lowest board, open toward the robot (-x)
and at the back; everything tall stands on its back half, so it hides little of the
work area from the front camera.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from aed_tasks.catalogue import Colour, ObjectSpec, object_colours
from aed_tasks.scene import UPRIGHT, physical_material, render_material

# Shape families per split (disjoint: a novel environment never shows a base shape).
CUBE_SHAPES = {"base": ("magic_cube_3x3", "die_pips"), "novel": ("magic_cube_2x2", "die_numbers")}
BOX_SHAPES = {
    "base": ("storage_box_plain", "storage_box_rimmed"),
    "novel": ("storage_box_handles", "storage_box_footed"),
}
SHELF_SHAPES = {
    "base": ("bookshelf_stepped", "bookshelf_ladder"),
    "novel": ("bookshelf_posts", "bookshelf_cabinet"),
}

BOARD = 0.015  # thickness of the shelf's boards and panels
# The under-shelf board starts this far behind the front edges of the shelf's sides: a
# top-down Panda hand reaches 2 cm past its fingertips, so a flush board would stop the
# push with the box still 2 cm outside.
SHELF_RECESS = 0.05
BOOK_ROW_DEPTH = 0.11  # books stand on the back part of the board, clear of the pushing arm
CELL = 32  # texture pixels per cube face


def spec_rng(spec: ObjectSpec) -> np.random.Generator:
    """A generator fixed by the spec alone: details (stickers, books) never drift."""
    return np.random.default_rng(zlib.crc32(repr(spec).encode()))


# --- toy cube --------------------------------------------------------------------------------
# Cells of SAPIEN's box UV atlas (4 columns x 3 rows): face normal -> (column, row).
FACE_CELLS = {"+z": (1, 1), "-z": (3, 1), "+x": (2, 1), "-x": (0, 1), "+y": (1, 2), "-y": (1, 0)}
DIE_FACES = {"+z": 1, "-z": 6, "+x": 2, "-x": 5, "+y": 3, "-y": 4}  # opposite faces sum to 7
PIPS = {
    1: [(0.5, 0.5)],
    2: [(0.25, 0.25), (0.75, 0.75)],
    3: [(0.25, 0.25), (0.5, 0.5), (0.75, 0.75)],
    4: [(0.25, 0.25), (0.25, 0.75), (0.75, 0.25), (0.75, 0.75)],
    5: [(0.25, 0.25), (0.25, 0.75), (0.5, 0.5), (0.75, 0.25), (0.75, 0.75)],
    6: [(0.25, 0.25), (0.25, 0.5), (0.25, 0.75), (0.75, 0.25), (0.75, 0.5), (0.75, 0.75)],
}
# Seven-segment digits: segments a (top), b, c (right), d (bottom), e, f (left), g (middle).
SEGMENTS = {1: "bc", 2: "abged", 3: "abgcd", 4: "fgbc", 5: "afgcd", 6: "afgedc"}


def _rgb(colour: Colour) -> np.ndarray:
    return np.asarray(colour[:3]) * 255


def _rounded_mask(radius: float) -> np.ndarray:
    """Inside (1) a rounded square filling a cell: the die's rounded-corner look."""
    v = (np.arange(CELL) + 0.5) / CELL
    dx = np.maximum(np.abs(v[None, :] - 0.5) - (0.5 - radius), 0)
    dy = np.maximum(np.abs(v[:, None] - 0.5) - (0.5 - radius), 0)
    return np.hypot(dx, dy) <= radius


def _sticker_cell(colours: list[np.ndarray], n: int) -> np.ndarray:
    """An n x n grid of coloured stickers on a black core."""
    cell = np.full((CELL, CELL, 3), 20.0)
    step, gap = CELL / n, max(CELL // 16, 1)
    for i in range(n):
        for j in range(n):
            r0, c0 = int(i * step) + gap, int(j * step) + gap
            cell[r0 : int((i + 1) * step) - gap, c0 : int((j + 1) * step) - gap] = colours[
                i * n + j
            ]
    return cell


def _pip_cell(count: int, body: np.ndarray, ink: np.ndarray) -> np.ndarray:
    cell = np.empty((CELL, CELL, 3))
    cell[:] = body
    v = (np.arange(CELL) + 0.5) / CELL
    for py, px in PIPS[count]:
        cell[np.hypot(v[:, None] - py, v[None, :] - px) < 0.1] = ink
    return cell


def _digit_cell(digit: int, body: np.ndarray, ink: np.ndarray) -> np.ndarray:
    """A seven-segment numeral, drawn so that it reads upright from the front camera."""
    glyph = np.zeros((CELL, CELL), bool)
    x0, x1, y0, y1, y2, w = 10, 22, 6, 16, 26, 3
    bars = {
        "a": (y0, y0 + w, x0, x1),
        "g": (y1 - 1, y1 + 2, x0, x1),
        "d": (y2 - w, y2, x0, x1),
        "f": (y0, y1 + 1, x0, x0 + w),
        "b": (y0, y1 + 1, x1 - w, x1),
        "e": (y1, y2, x0, x0 + w),
        "c": (y1, y2, x1 - w, x1),
    }
    for segment in SEGMENTS[digit]:
        r0, r1, c0, c1 = bars[segment]
        glyph[r0:r1, c0:c1] = True
    cell = np.empty((CELL, CELL, 3))
    cell[:] = body
    cell[glyph.T] = (
        ink  # transposed: reads upright on the top and front faces, seen from the camera
    )
    return cell


def toy_palette(spec: ObjectSpec) -> list[np.ndarray]:
    """The toy's colours: its own colour first, then the rest of its split's palette."""
    split = "base" if spec.shape in CUBE_SHAPES["base"] else "novel"
    palette = [c for c in object_colours(split) if c != spec.material.colour]
    return [_rgb(spec.material.colour)] + [_rgb(c) for c in palette]


def toy_atlas(spec: ObjectSpec) -> np.ndarray:
    """The RGBA atlas texture (4 x 3 face cells) of a magic cube or a die."""
    rng = spec_rng(spec)
    colours = toy_palette(spec)
    atlas = np.zeros((3 * CELL, 4 * CELL, 3))
    if spec.shape.startswith("magic_cube"):
        n = int(spec.shape[-1])
        faces = colours[:6]
        stickers = [
            faces[k] for k in range(6) for _ in range(n * n)
        ]  # a scrambled cube: a shuffled set
        order = rng.permutation(len(stickers))
    for k, (face, (col, row)) in enumerate(FACE_CELLS.items()):
        if spec.shape.startswith("magic_cube"):
            cell = _sticker_cell([stickers[i] for i in order[k * n * n : (k + 1) * n * n]], n)
        else:
            body, ink = (
                colours[0],
                (np.full(3, 25.0) if colours[0].mean() > 110 else np.full(3, 235.0)),
            )
            draw = _pip_cell if spec.shape == "die_pips" else _digit_cell
            cell = draw(DIE_FACES[face], body, ink)
            cell[~_rounded_mask(0.18)] = body * 0.55  # darker, rounded edges
        atlas[row * CELL : (row + 1) * CELL, col * CELL : (col + 1) * CELL] = cell
    rgba = np.concatenate([atlas, np.full((*atlas.shape[:2], 1), 255.0)], axis=2)
    return np.ascontiguousarray(rgba.clip(0, 255).astype(np.uint8))


@lru_cache(maxsize=64)
def _toy_texture(spec: ObjectSpec) -> sapien.render.RenderTexture2D:
    return sapien.render.RenderTexture2D(
        toy_atlas(spec), "R8G8B8A8Unorm", filter_mode="nearest", srgb=True
    )


def build_toy_cube(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, density: float = 500.0
) -> Actor:
    """A magic cube or a die of edge `spec.size[0]`, origin at its centre."""
    half = spec.size[0] / 2
    material = sapien.render.RenderMaterial(
        base_color=[1, 1, 1, 1], roughness=spec.material.roughness
    )
    material.base_color_texture = _toy_texture(spec)
    builder = scene.create_actor_builder()
    builder.add_box_collision(
        half_size=[half] * 3, density=density, material=physical_material(1.2)
    )
    builder.add_box_visual(half_size=[half] * 3, material=material)
    builder.initial_pose = sapien.Pose(p=[0, 0, half])
    return builder.build(name=name)


# --- storage box -----------------------------------------------------------------------------
@dataclass(frozen=True)
class BoxGeometry:
    """Outer depth (x), width (y), height, wall thickness and floor height of a storage box."""

    depth: float
    width: float
    height: float
    wall: float
    floor: float  # top of the box's floor above its bottom (feet raise it)

    @classmethod
    def of(cls, spec: ObjectSpec) -> BoxGeometry:
        depth, width, height, wall = spec.size
        feet = 0.008 if spec.shape == "storage_box_footed" else 0.0
        return cls(depth, width, height, wall, feet + wall)

    @property
    def inner_half(self) -> tuple[float, float]:
        return self.depth / 2 - self.wall, self.width / 2 - self.wall


def _box(
    builder: sapien.ActorBuilder, centre, half, material, density: float | None, friction=None
) -> None:
    pose = sapien.Pose(p=list(centre))
    if density is not None:
        builder.add_box_collision(
            pose=pose, half_size=list(half), density=density, material=friction
        )
    builder.add_box_visual(pose=pose, half_size=list(half), material=material)


def build_storage_box(
    scene: ManiSkillScene, spec: ObjectSpec, name: str, density: float = 450.0
) -> Actor:
    """An open-top box (origin at the middle of its bottom face), light enough to push."""
    g = BoxGeometry.of(spec)
    material = render_material(spec.material)
    trim = sapien.render.RenderMaterial(
        base_color=[*(np.asarray(spec.material.colour[:3]) * 0.45), 1.0], roughness=0.6
    )
    slide = physical_material(0.5)
    builder = scene.create_actor_builder()
    base_z = g.floor - g.wall
    dx, dy, wall_h = g.depth / 2, g.width / 2, g.height - base_z
    _box(builder, (0, 0, base_z + g.wall / 2), (dx, dy, g.wall / 2), material, density, slide)
    for sx in (-1, 1):  # front and back walls span the full width
        _box(
            builder,
            (sx * (dx - g.wall / 2), 0, base_z + wall_h / 2),
            (g.wall / 2, dy, wall_h / 2),
            material,
            density,
            slide,
        )
    for sy in (-1, 1):
        _box(
            builder,
            (0, sy * (dy - g.wall / 2), base_z + wall_h / 2),
            (dx - g.wall, g.wall / 2, wall_h / 2),
            material,
            density,
            slide,
        )
    if spec.shape == "storage_box_footed":
        for sx in (-1, 1):
            for sy in (-1, 1):
                _box(
                    builder,
                    (sx * (dx - 0.012), sy * (dy - 0.012), base_z / 2),
                    (0.01, 0.01, base_z / 2),
                    trim,
                    density,
                    slide,
                )
    elif spec.shape == "storage_box_rimmed":  # a contrasting band along the top of the walls
        band = 0.008
        for sx in (-1, 1):
            _box(
                builder,
                (sx * (dx - g.wall / 2), 0, g.height - band / 2),
                (g.wall / 2 + 0.001, dy + 0.001, band / 2),
                trim,
                None,
            )
        for sy in (-1, 1):
            _box(
                builder,
                (0, sy * (dy - g.wall / 2), g.height - band / 2),
                (dx - g.wall, g.wall / 2 + 0.001, band / 2),
                trim,
                None,
            )
    elif spec.shape == "storage_box_handles":  # dark handle slots on the side walls
        for sy in (-1, 1):
            _box(
                builder,
                (0, sy * (dy + 0.0005), g.height * 0.72),
                (g.depth * 0.22, 0.001, g.height * 0.1),
                trim,
                None,
            )
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build(name=name)


# --- bookshelf -------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShelfGeometry:
    """Depth (x), inner width (y) and clearance below the board; total height of a shelf.

    The free space under the board, x in [0, depth], |y| < inner_width / 2 in the shelf's
    frame (origin at the middle of its front edge, on the table), is "under the shelf".
    """

    depth: float
    inner_width: float
    clearance: float
    height: float

    @classmethod
    def of(cls, spec: ObjectSpec) -> ShelfGeometry:
        return cls(*spec.size)

    @property
    def board_top(self) -> float:
        return self.clearance + BOARD


def build_bookshelf(scene: ManiSkillScene, spec: ObjectSpec, name: str) -> Actor:
    """A low bookshelf: sides, a recessed board above free space, a back part with books.

    Kinematic (immovable, but posed per episode, also in GPU simulation).
    """
    g = ShelfGeometry.of(spec)
    rng = spec_rng(spec)
    wood = render_material(spec.material)
    half_w = g.inner_width / 2
    top, d, upper = g.board_top, g.depth, g.height - g.board_top
    builder = scene.create_actor_builder()
    # the board the box slides under (recessed), and the back panel above it
    _box(
        builder,
        (SHELF_RECESS + (d - SHELF_RECESS) / 2, 0, g.clearance + BOARD / 2),
        ((d - SHELF_RECESS) / 2, half_w + BOARD, BOARD / 2),
        wood,
        500.0,
    )
    _box(
        builder,
        (d - BOARD / 2, 0, top + upper / 2),
        (BOARD / 2, half_w + BOARD, upper / 2),
        wood,
        500.0,
    )
    side_y = half_w + BOARD / 2
    if spec.shape in ("bookshelf_stepped", "bookshelf_cabinet"):  # solid side panels
        for sy in (-1, 1):
            _box(builder, (d / 2, sy * side_y, top / 2), (d / 2, BOARD / 2, top / 2), wood, 500.0)
            back = d * (0.5 if spec.shape == "bookshelf_stepped" else 0.42)
            _box(
                builder,
                (d - back / 2, sy * side_y, top + upper / 2),
                (back / 2, BOARD / 2, upper / 2),
                wood,
                500.0,
            )
        if spec.shape == "bookshelf_cabinet":  # a lid over the back part and a middle divider
            _box(
                builder,
                (d - d * 0.21, 0, g.height - BOARD / 2),
                (d * 0.21, half_w + BOARD, BOARD / 2),
                wood,
                500.0,
            )
            _box(
                builder,
                (d - d * 0.21, 0, top + upper / 2),
                (d * 0.21, BOARD / 2, upper / 2),
                wood,
                500.0,
            )
    else:  # four corner posts and rails
        post = 0.012
        for sx in (post, d - post):
            for sy in (-1, 1):
                if spec.shape == "bookshelf_posts":
                    pose = sapien.Pose(p=[sx, sy * (half_w + post), g.height / 2], q=UPRIGHT)
                    builder.add_cylinder_collision(pose=pose, radius=post, half_length=g.height / 2)
                    builder.add_cylinder_visual(
                        pose=pose, radius=post, half_length=g.height / 2, material=wood
                    )
                else:
                    _box(
                        builder,
                        (sx, sy * (half_w + post), g.height / 2),
                        (post, post, g.height / 2),
                        wood,
                        500.0,
                    )
        for sy in (-1, 1):  # side rails under the board and at the top
            _box(
                builder,
                (d / 2, sy * (half_w + post), g.clearance - 0.01),
                (d / 2, post * 0.7, 0.01),
                wood,
                500.0,
            )
            _box(
                builder,
                (d / 2, sy * (half_w + post), g.height - 0.01),
                (d / 2 - post, post * 0.7, 0.01),
                wood,
                500.0,
            )
    _add_books(builder, g, rng, spec)
    builder.initial_pose = sapien.Pose(p=[0, 0, 0])
    return builder.build_kinematic(name=name)


def _add_books(
    builder: sapien.ActorBuilder, g: ShelfGeometry, rng: np.random.Generator, spec: ObjectSpec
) -> None:
    """Books on the back of the board (visuals) inside one collision box for the whole row."""
    split = "base" if spec.shape in SHELF_SHAPES["base"] else "novel"
    palette = object_colours(split)
    half_w, top = g.inner_width / 2, g.board_top
    x_back = g.depth - BOARD
    room = g.height - top - (BOARD if spec.shape == "bookshelf_cabinet" else 0.0) - 0.004
    lying = spec.shape == "bookshelf_posts"  # novel posts shelf: stacks of books lying flat
    y, y_end = -half_w + 0.01, half_w - 0.01
    tallest = 0.0
    while True:
        depth = float(rng.uniform(0.08, BOOK_ROW_DEPTH))
        colour = palette[int(rng.integers(len(palette)))]
        material = sapien.render.RenderMaterial(base_color=list(colour), roughness=0.7)
        if lying:
            width = float(rng.uniform(0.07, 0.1))
            if y + width > y_end:
                break
            z = top
            for _ in range(int(rng.integers(2, 5))):
                thick = float(rng.uniform(0.012, 0.022))
                if z + thick > top + room * 0.8:
                    break
                _box(
                    builder,
                    (x_back - depth / 2, y + width / 2, z + thick / 2),
                    (depth / 2, width / 2, thick / 2),
                    material,
                    None,
                )
                material = sapien.render.RenderMaterial(
                    base_color=list(palette[int(rng.integers(len(palette)))]), roughness=0.7
                )
                z += thick
            tallest = max(tallest, z - top)
            y += width + 0.01
        else:
            thick = float(rng.uniform(0.014, 0.03))
            if y + thick > y_end:
                break
            height = float(rng.uniform(0.6, 0.95)) * room
            _box(
                builder,
                (x_back - depth / 2, y + thick / 2, top + height / 2),
                (depth / 2, thick / 2, height / 2),
                material,
                None,
            )
            tallest = max(tallest, height)
            y += thick + float(rng.uniform(0.0, 0.012))
    if tallest > 0:
        centre = (x_back - BOOK_ROW_DEPTH / 2, 0, top + tallest / 2)
        builder.add_box_collision(
            pose=sapien.Pose(p=list(centre)), half_size=[BOOK_ROW_DEPTH / 2, half_w, tallest / 2]
        )

"""Environment catalogues: the fixed, seeded list of environments of each task and split.

An *environment* (paper: base / novel environment) fixes everything visual about a scene:
background materials, lighting, the interactive objects and the distractors. Episodes
inside one environment only re-sample poses. Base and novel catalogues draw from
disjoint pools (see `aed_tasks.assets`), so a policy deployed in a novel environment has
never seen its textures, colours or object shapes.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from aed_tasks.assets import OBJECT_COLOURS, SPLITS, texture_names

Colour = tuple[float, float, float, float]

# Shapes of the environment distractors (unrelated clutter), disjoint by split.
DISTRACTOR_SHAPES: dict[str, tuple[str, ...]] = {
    "base": ("box", "ball", "capsule", "vase"),
    "novel": ("cylinder", "bottle", "cone", "spindle"),
}

# How each shape is drawn: its generator and the form it gives. Within one object role, base
# and novel shapes share no entry (tests/test_catalogues.py); a revolved mesh ("revolve:")
# is also compared by its profile in `aed_tasks.assets.MESH_PROFILES`, sections aside.
SHAPE_GENERATORS: dict[str, str] = {
    # distractors
    "box": "box",
    "ball": "sphere",
    "capsule": "capsule",
    "vase": "revolve:vase",
    "cylinder": "cylinder",
    "bottle": "revolve:bottle",
    "cone": "revolve:cone",
    "spindle": "revolve:spindle",
    # Close Drawer: cabinets and drawer handles
    "cabinet_plain": "cabinet:bare shell",
    "cabinet_plinth": "cabinet:shell on a recessed plinth",
    "cabinet_legged": "cabinet:shell on four legs",
    "cabinet_crowned": "cabinet:shell with face frame and crown",
    "drawer_bar": "handle:horizontal bar on two posts",
    "drawer_knob": "handle:one cylindrical knob",
    "drawer_ledge": "handle:thin full-width ledge",
    "drawer_vertical_bar": "handle:vertical bar on two posts",
    "drawer_twin_balls": "handle:two balls on stems",
    "drawer_block": "handle:one thick block",
    # Press Button
    "button_housing_block": "box",
    "button_housing_puck": "cylinder",
    "button_housing_hex": "prism:hexagon",
    "button_housing_plinth": "stepped boxes",
    "button_cap_disc": "cylinder",
    "button_cap_mushroom": "stacked cylinders (neck, head)",
    "button_cap_square": "box",
    "button_cap_dome": "revolve:button_cap_dome",
    # Pick & Place
    "mug_cylinder": "revolve:mug_cylinder",
    "cup_tapered": "revolve:cup_tapered",
    "mug_barrel": "revolve:mug_barrel",
    "cup_waisted": "revolve:cup_waisted",
    "bowl_round": "revolve:bowl_round",
    "bowl_straight": "revolve:bowl_straight",
    "bowl_basin": "revolve:bowl_basin",
    "bowl_lipped": "revolve:bowl_lipped",
    # Move Glass Cup
    "glass_tumbler": "revolve:glass_tumbler",
    "glass_tapered": "revolve:glass_tapered",
    "glass_octagonal": "revolve:glass_octagonal",
    "glass_round_bottom": "revolve:glass_round_bottom",
    "coaster_round": "cylinder",
    "coaster_square": "box",
    "coaster_hexagon": "prism:hexagon",
    "coaster_oval": "prism:oval",
    # Organize Table
    "item_block": "box",
    "item_book": "box with covers and pages",
    "item_canister": "lying drum with lids",
    "item_loaf": "box under a half drum roof",
    "shelf_slab": "shelf:solid side slabs",
    "shelf_ledge": "shelf:slabs with a front ledge",
    "shelf_posts": "shelf:square posts",
    "shelf_columns": "shelf:round columns",
    # Back to Box
    "magic_cube_3x3": "cube:3x3 sticker grid",
    "die_pips": "cube:pips",
    "magic_cube_2x2": "cube:2x2 sticker grid",
    "die_numbers": "cube:numerals",
    "storage_box_plain": "open box:plain",
    "storage_box_rimmed": "open box:rim band",
    "storage_box_handles": "open box:handle slots",
    "storage_box_footed": "open box:on feet",
    "bookshelf_stepped": "bookshelf:stepped side panels",
    "bookshelf_ladder": "bookshelf:ladder frame",
    "bookshelf_posts": "bookshelf:posts, books lying flat",
    "bookshelf_cabinet": "bookshelf:lidded cabinet",
    # Factory Packing
    "box_plain": "packing box:plain",
    "box_flanged": "packing box:flanged rim",
    "box_handled": "packing box:end handles",
    "box_cornered": "packing box:corner posts",
    "product_carton": "box",
    "product_can": "cylinder",
    "product_tub": "revolve:product_tub",
    "product_jar": "revolve:product_jar",
    "conveyor_railed": "conveyor:side rails",
    "conveyor_rollered": "conveyor:end drums and motor housing",
}


@dataclass(frozen=True)
class MaterialSpec:
    """A surface: a base colour, optionally modulated by a generated texture."""

    colour: Colour = (1.0, 1.0, 1.0, 1.0)
    texture: str | None = None
    roughness: float = 0.7
    metallic: float = 0.0


@dataclass(frozen=True)
class ObjectSpec:
    """One object of an environment: a shape family, a size and a material."""

    shape: str
    size: tuple[float, ...]
    material: MaterialSpec


@dataclass(frozen=True)
class LightSpec:
    """A directional light; the first light of an environment casts the shadows."""

    direction: tuple[float, float, float]
    colour: tuple[float, float, float]


@dataclass(frozen=True)
class EnvironmentSpec:
    """Everything fixed about one environment of a task's catalogue."""

    task: str
    split: str
    index: int
    floor: MaterialSpec
    wall: MaterialSpec
    table: MaterialSpec
    ambient: tuple[float, float, float]
    lights: tuple[LightSpec, ...]
    objects: dict[str, ObjectSpec] = field(default_factory=dict)
    distractors: tuple[ObjectSpec, ...] = ()

    def textures(self) -> set[str]:
        mats = [self.floor, self.wall, self.table]
        mats += [o.material for o in self.objects.values()] + [d.material for d in self.distractors]
        return {m.texture for m in mats if m.texture is not None}

    def colours(self) -> set[Colour]:
        objs = list(self.objects.values()) + list(self.distractors)
        return {o.material.colour for o in objs}

    def shapes(self) -> set[str]:
        return {o.shape for o in self.objects.values()} | {d.shape for d in self.distractors}


def catalogue_rng(task: str, split: str, index: int) -> np.random.Generator:
    """A generator seeded by (task, split, index) alone: catalogues never drift."""
    digest = hashlib.sha256(f"{task}/{split}/{index}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def check_split(split: str) -> str:
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
    return split


def pick(rng: np.random.Generator, options: Sequence, k: int | None = None):
    """One option (k=None) or k distinct options, uniformly."""
    if k is None:
        return options[int(rng.integers(len(options)))]
    return [options[i] for i in rng.choice(len(options), size=k, replace=False)]


def object_colours(split: str) -> tuple[Colour, ...]:
    return OBJECT_COLOURS[check_split(split)]


def sample_material(
    rng: np.random.Generator, split: str, textured: bool = True, tint: float = 0.0
) -> MaterialSpec:
    """A split material: a split texture (or none), under a near-white or split-coloured tint."""
    colour: Colour = (1.0, 1.0, 1.0, 1.0)
    if tint > 0:
        c = np.asarray(pick(rng, object_colours(split))[:3])
        colour = tuple(float(v) for v in (1 - tint) + tint * c) + (1.0,)
    texture = pick(rng, texture_names(split)) if textured else None
    return MaterialSpec(colour=colour, texture=texture, roughness=float(rng.uniform(0.4, 0.9)))


def sample_lighting(
    rng: np.random.Generator,
) -> tuple[tuple[float, float, float], tuple[LightSpec, ...]]:
    """Ambient light plus two or three directional lights (the first one shadowed)."""
    ambient = tuple(float(v) for v in np.full(3, rng.uniform(0.25, 0.4)))
    lights = []
    for i in range(int(rng.integers(2, 4))):
        azimuth, elevation = rng.uniform(0, 2 * np.pi), rng.uniform(np.pi / 4, np.pi / 2.2)
        direction = (
            -np.cos(elevation) * np.cos(azimuth),
            -np.cos(elevation) * np.sin(azimuth),
            -np.sin(elevation),
        )
        warmth = rng.uniform(-0.08, 0.08)
        strength = rng.uniform(0.9, 1.4) if i == 0 else rng.uniform(0.2, 0.5)
        colour = (strength * (1 + warmth), strength, strength * (1 - warmth))
        lights.append(
            LightSpec(tuple(float(v) for v in direction), tuple(float(v) for v in colour))
        )
    return ambient, tuple(lights)


def sample_distractors(
    rng: np.random.Generator, split: str, count: int, exclude: Sequence[Colour] = ()
) -> tuple[ObjectSpec, ...]:
    """`count` unrelated objects of the split's distractor shapes and colours."""
    colours = [c for c in object_colours(split) if c not in exclude] or list(object_colours(split))
    out = []
    for _ in range(count):
        shape = pick(rng, DISTRACTOR_SHAPES[split])
        size = (
            float(rng.uniform(0.025, 0.04)),
            float(rng.uniform(0.05, 0.11)),
        )  # radius / half-extent, height
        out.append(
            ObjectSpec(
                shape,
                size,
                MaterialSpec(colour=pick(rng, colours), roughness=float(rng.uniform(0.3, 0.8))),
            )
        )
    return tuple(out)


def sample_background(rng: np.random.Generator, split: str) -> dict[str, MaterialSpec]:
    """Floor, wall and table materials, each from the split's textures."""
    return {
        "floor": sample_material(rng, split),
        "wall": sample_material(rng, split, tint=0.15),
        "table": sample_material(rng, split),
    }


@dataclass(frozen=True)
class Catalogue:
    """The environments of one task and split, indexed 0..n-1."""

    task: str
    split: str
    environments: tuple[EnvironmentSpec, ...]

    def __len__(self) -> int:
        return len(self.environments)

    def __iter__(self) -> Iterator[EnvironmentSpec]:
        return iter(self.environments)

    def __getitem__(self, index: int) -> EnvironmentSpec:
        if not 0 <= index < len(self.environments):
            raise IndexError(
                f"env_index {index} out of range: {self.task} {self.split} has "
                f"{len(self.environments)} environments (0..{len(self.environments) - 1})"
            )
        return self.environments[index]

"""Asset pools of the benchmark: generated textures, mesh profiles, palettes, by split.

Base and novel environments draw from disjoint pools (patterns, palettes, shapes), which
is what makes a novel environment novel. `scripts/generate_assets.py` writes the files;
this module names them and loads them (cached, so a reconfiguring reset stays cheap).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

ASSET_DIR = Path(__file__).resolve().parent.parent / "assets"
SPLITS = ("base", "novel")

# Texture pattern families per split (disjoint), each rendered in every palette pair below.
TEXTURE_PATTERNS: dict[str, tuple[str, ...]] = {
    "base": ("wood", "checker", "stripes", "noise"),
    "novel": ("marble", "tiles", "dots", "weave"),
}
TEXTURE_PALETTES: dict[str, tuple[tuple[tuple[int, int, int], tuple[int, int, int]], ...]] = {
    "base": (
        ((182, 128, 82), (120, 78, 44)),  # oak
        ((205, 205, 195), (150, 150, 140)),  # concrete
        ((120, 150, 190), (70, 95, 140)),  # slate blue
        ((190, 170, 120), (140, 120, 80)),  # sand
        ((150, 90, 90), (100, 55, 55)),  # brick
        ((110, 140, 100), (70, 95, 65)),  # moss
    ),
    "novel": (
        ((120, 215, 190), (60, 160, 140)),  # mint
        ((70, 70, 85), (35, 35, 45)),  # charcoal
        ((235, 160, 200), (185, 105, 150)),  # rose
        ((30, 175, 165), (5, 120, 115)),  # petrol
        ((235, 215, 60), (190, 165, 20)),  # mustard
        ((175, 130, 230), (120, 80, 175)),  # lilac
    ),
}

# Colours of interactive objects and distractors (RGBA in [0, 1]); disjoint by split.
OBJECT_COLOURS: dict[str, tuple[tuple[float, float, float, float], ...]] = {
    "base": (
        (0.85, 0.15, 0.12, 1.0),  # red
        (0.95, 0.55, 0.10, 1.0),  # orange
        (0.95, 0.85, 0.15, 1.0),  # yellow
        (0.20, 0.65, 0.25, 1.0),  # green
        (0.15, 0.35, 0.85, 1.0),  # blue
        (0.55, 0.25, 0.70, 1.0),  # purple
        (0.92, 0.92, 0.90, 1.0),  # white
    ),
    "novel": (
        (0.95, 0.45, 0.65, 1.0),  # pink
        (0.10, 0.60, 0.60, 1.0),  # teal
        (0.50, 0.30, 0.15, 1.0),  # brown
        (0.50, 0.55, 0.15, 1.0),  # olive
        (0.10, 0.12, 0.35, 1.0),  # navy
        (0.45, 0.45, 0.48, 1.0),  # grey
        (0.15, 0.80, 0.85, 1.0),  # cyan
    ),
}

# Visual meshes as (radius, height) outlines in a unit box (r <= 0.5, 0 <= z <= 1), revolved
# around z by the generator and scaled per environment to (diameter, diameter, height).
MESH_PROFILES: dict[str, dict] = {
    # drinking vessels (Pick & Place, Move Glass Cup)
    "mug_cylinder": {"outline": [(0, 0), (0.5, 0), (0.5, 1), (0.44, 1), (0.44, 0.1), (0, 0.1)]},
    "cup_tapered": {"outline": [(0, 0), (0.4, 0), (0.5, 1), (0.45, 1), (0.36, 0.1), (0, 0.1)]},
    "mug_barrel": {
        "outline": [
            (0, 0),
            (0.42, 0),
            (0.5, 0.5),
            (0.43, 1),
            (0.38, 1),
            (0.44, 0.5),
            (0.36, 0.1),
            (0, 0.1),
        ]
    },
    "cup_waisted": {
        "outline": [
            (0, 0),
            (0.5, 0),
            (0.42, 0.5),
            (0.5, 1),
            (0.45, 1),
            (0.37, 0.5),
            (0.44, 0.1),
            (0, 0.1),
        ]
    },
    # bowls
    "bowl_round": {
        "outline": [
            (0, 0),
            (0.3, 0),
            (0.45, 0.5),
            (0.5, 1),
            (0.46, 1),
            (0.41, 0.5),
            (0.28, 0.2),
            (0, 0.2),
        ]
    },
    "bowl_straight": {"outline": [(0, 0), (0.4, 0), (0.5, 1), (0.46, 1), (0.37, 0.2), (0, 0.2)]},
    "bowl_basin": {
        "outline": [
            (0, 0),
            (0.45, 0),
            (0.5, 0.3),
            (0.5, 1),
            (0.46, 1),
            (0.46, 0.3),
            (0.42, 0.2),
            (0, 0.2),
        ]
    },
    "bowl_lipped": {
        "outline": [
            (0, 0),
            (0.34, 0),
            (0.44, 0.85),
            (0.5, 0.9),
            (0.5, 1),
            (0.4, 1),
            (0.31, 0.2),
            (0, 0.2),
        ]
    },
    # environment distractors (solid)
    "vase": {"outline": [(0, 0), (0.35, 0), (0.5, 0.4), (0.2, 0.85), (0.3, 1), (0, 1)]},
    "bottle": {"outline": [(0, 0), (0.5, 0), (0.5, 0.6), (0.2, 0.8), (0.2, 1), (0, 1)]},
    "cone": {"outline": [(0, 0), (0.5, 0), (0, 1)]},
    "spindle": {"outline": [(0, 0), (0.2, 0), (0.5, 0.5), (0.2, 1), (0, 1)]},
    # push buttons (Press Button): polygonal prisms of unit height
    "button_housing_hex": {"outline": [(0, 0), (0.5, 0), (0.5, 1), (0, 1)], "sections": 6},
    "button_cap_dome": {
        "outline": [(0, 0), (0.5, 0), (0.5, 0.3), (0.433, 0.65), (0.25, 0.9), (0, 1)]
    },
    # glasses, water drops and coasters (Move Glass Cup); a glass's collision follows its outer wall
    "glass_tumbler": {"outline": [(0, 0), (0.5, 0), (0.5, 1), (0.45, 1), (0.45, 0.1), (0, 0.1)]},
    "glass_tapered": {"outline": [(0, 0), (0.41, 0), (0.5, 1), (0.45, 1), (0.365, 0.1), (0, 0.1)]},
    "glass_octagonal": {  # eight facets over a chamfered foot
        "outline": [
            (0, 0),
            (0.42, 0),
            (0.5, 0.35),
            (0.5, 1),
            (0.45, 1),
            (0.45, 0.35),
            (0.37, 0.1),
            (0, 0.1),
        ],
        "sections": 8,
    },
    "glass_round_bottom": {  # a rounded belly under a straight rim
        "outline": [
            (0, 0),
            (0.3, 0),
            (0.45, 0.25),
            (0.5, 0.55),
            (0.5, 1),
            (0.45, 1),
            (0.45, 0.55),
            (0.4, 0.25),
            (0.25, 0.1),
            (0, 0.1),
        ]
    },
    "glass_water_drop": {
        "outline": [(0, 0), (0.354, 0.146), (0.5, 0.5), (0.354, 0.854), (0, 1)],
        "sections": 8,
    },
    "coaster_hexagon": {"outline": [(0, 0), (0.5, 0), (0.5, 1), (0, 1)], "sections": 6},
    "coaster_oval": {"outline": [(0, 0), (0.5, 0), (0.5, 1), (0, 1)]},
    # products (Factory Packing, novel split): a tub widening to a lip, and a necked jar
    "product_tub": {"outline": [(0, 0), (0.4, 0), (0.47, 0.86), (0.5, 0.88), (0.5, 1), (0, 1)]},
    "product_jar": {
        "outline": [(0, 0), (0.5, 0), (0.5, 0.72), (0.36, 0.84), (0.36, 1), (0, 1)],
        "sections": 16,
    },
}
for _profile in MESH_PROFILES.values():
    _profile.setdefault("sections", 24)


def texture_names(split: str) -> list[str]:
    """All texture files of a split, as paths relative to the texture folder."""
    palettes = TEXTURE_PALETTES[split]
    return [f"{split}/{p}_{c}.png" for p in TEXTURE_PATTERNS[split] for c in range(len(palettes))]


def texture_path(name: str) -> Path:
    path = ASSET_DIR / "textures" / name
    if not path.is_file():
        raise FileNotFoundError(
            f"texture {name!r} missing at {path}; run scripts/generate_assets.py"
        )
    return path


def mesh_path(name: str) -> Path:
    path = ASSET_DIR / "meshes" / f"{name}.obj"
    if not path.is_file():
        raise FileNotFoundError(f"mesh {name!r} missing at {path}; run scripts/generate_assets.py")
    return path


@cache
def load_texture(name: str):
    """A SAPIEN texture, loaded once per process (textures are immutable and shared)."""
    import sapien

    return sapien.render.RenderTexture2D(str(texture_path(name)))

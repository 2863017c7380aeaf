"""Generate the textures and meshes the AED tasks load (written to assets/, committed).

Everything is procedural and seeded, so the output is reproducible and nothing is ever
downloaded. Base and novel splits draw from disjoint pattern families and palettes:
base and novel environments share no texture, and `aed_tasks.catalogue` keeps the
object shapes and colour sets disjoint as well.

    python scripts/generate_assets.py            # (re)writes assets/textures and assets/meshes
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import cv2
import numpy as np
import trimesh

from aed_tasks.assets import ASSET_DIR, MESH_PROFILES, TEXTURE_PALETTES, TEXTURE_PATTERNS

logger = logging.getLogger(__name__)
SIZE = 128


def _mix(mask: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (mask[..., None] * a + (1.0 - mask[..., None]) * b).astype(np.uint8)


def _smooth_noise(rng: np.random.Generator, cells: int) -> np.ndarray:
    """Value noise: a coarse random grid upsampled smoothly, tileable enough for floors."""
    grid = rng.random((cells, cells)).astype(np.float32)
    return cv2.resize(grid, (SIZE, SIZE), interpolation=cv2.INTER_CUBIC).clip(0, 1)


def pattern_mask(pattern: str, rng: np.random.Generator) -> np.ndarray:
    """A [0, 1] mask of one pattern family; two colours are then mixed through it."""
    y, x = np.mgrid[0:SIZE, 0:SIZE].astype(np.float32) / SIZE
    if pattern == "wood":
        rings = np.sin((x * 3 + _smooth_noise(rng, 4) * 1.5) * 2 * np.pi * 6)
        return (rings * 0.5 + 0.5) ** 2
    if pattern == "checker":
        n = int(rng.integers(4, 9))
        return ((np.floor(x * n) + np.floor(y * n)) % 2).astype(np.float32)
    if pattern == "stripes":
        n, angle = int(rng.integers(5, 12)), rng.uniform(0, np.pi)
        return (np.sin((x * np.cos(angle) + y * np.sin(angle)) * 2 * np.pi * n) > 0).astype(
            np.float32
        )
    if pattern == "noise":
        return 0.6 * _smooth_noise(rng, 8) + 0.4 * _smooth_noise(rng, 32)
    if pattern == "marble":
        turbulence = _smooth_noise(rng, 6) * 2 + _smooth_noise(rng, 16)
        return np.abs(np.sin((x + y) * 8 + turbulence * 3)) ** 0.5
    if pattern == "tiles":
        n = int(rng.integers(3, 6))
        gx, gy = (x * n) % 1, (y * n) % 1
        grout = (np.minimum(np.minimum(gx, 1 - gx), np.minimum(gy, 1 - gy)) < 0.05).astype(
            np.float32
        )
        return 1.0 - grout * 0.9
    if pattern == "dots":
        n = int(rng.integers(5, 10))
        gx, gy = (x * n) % 1 - 0.5, (y * n) % 1 - 0.5
        return (np.hypot(gx, gy) < 0.28).astype(np.float32)
    if pattern == "weave":
        n = int(rng.integers(6, 12))
        a = (np.sin(x * 2 * np.pi * n) * np.sin(y * 2 * np.pi * n) > 0).astype(np.float32)
        return 0.5 * a + 0.5 * np.abs(np.sin(y * 2 * np.pi * n * 2))
    raise ValueError(
        f"unknown texture pattern {pattern!r}; known: {sorted(sum(TEXTURE_PATTERNS.values(), ()))}"
    )


def make_texture(pattern: str, colour_a: tuple, colour_b: tuple, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    mask = pattern_mask(pattern, rng)
    grain = 1.0 + 0.06 * (rng.random((SIZE, SIZE, 1)) - 0.5)
    rgb = _mix(mask, np.asarray(colour_a, np.float32), np.asarray(colour_b, np.float32))
    return (rgb * grain).clip(0, 255).astype(np.uint8)


def write_textures(out: Path) -> int:
    count = 0
    for split, patterns in TEXTURE_PATTERNS.items():
        palette = TEXTURE_PALETTES[split]
        for p, pattern in enumerate(patterns):
            for c, (colour_a, colour_b) in enumerate(palette):
                rgb = make_texture(
                    pattern, colour_a, colour_b, seed=1000 * p + c + (0 if split == "base" else 500)
                )
                path = out / "textures" / split / f"{pattern}_{c}.png"
                path.parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
                count += 1
    return count


def write_meshes(out: Path) -> int:
    """Unit-height visual meshes, one per object shape; collisions are built from primitives."""
    count = 0
    for name, profile in MESH_PROFILES.items():
        mesh = trimesh.creation.revolve(
            np.asarray(profile["outline"], dtype=float), sections=profile["sections"]
        )
        path = out / "meshes" / f"{name}.obj"
        path.parent.mkdir(parents=True, exist_ok=True)
        mesh.export(path)
        count += 1
    return count


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=ASSET_DIR)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    n_tex, n_mesh = write_textures(args.out), write_meshes(args.out)
    logger.info("wrote %d textures and %d meshes under %s", n_tex, n_mesh, args.out)


if __name__ == "__main__":
    main()

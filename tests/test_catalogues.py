"""Catalogues: sizes of the paper's table, determinism, base/novel disjointness by name and to the
eye."""

from __future__ import annotations

import functools
import itertools

import cv2
import numpy as np
import pytest

import aed_tasks
from aed_tasks.assets import MESH_PROFILES, OBJECT_COLOURS, TEXTURE_PALETTES, texture_path
from aed_tasks.base_env import DEMONSTRATOR_TINT
from aed_tasks.catalogue import SHAPE_GENERATORS

from .conftest import ALL_TASKS

PAPER_SIZES = {
    "CloseDrawer": (18, 18),
    "PressButton": (27, 18),
    "PickPlace": (90, 42),
    "MoveGlassCup": (42, 20),
    "OrganizeTable": (49, 25),
    "BackToBox": (60, 18),
    "FactoryPacking": (36, 12),
}


@pytest.mark.parametrize("task", ALL_TASKS)
def test_catalogue_sizes_match_the_paper(task):
    cls = aed_tasks.get_task(task)
    assert (len(cls.get_catalogue("base")), len(cls.get_catalogue("novel"))) == PAPER_SIZES[task]


@pytest.mark.parametrize("task", ALL_TASKS)
def test_base_and_novel_share_no_texture_colour_or_shape(task):
    cls = aed_tasks.get_task(task)
    pools = {}
    for split in ("base", "novel"):
        envs = cls.get_catalogue(split)
        pools[split] = (
            set().union(*(e.textures() for e in envs)),
            set().union(*(e.colours() for e in envs)),
            set().union(*(e.shapes() for e in envs)),
        )
        assert all(e.split == split for e in envs)
    for name, base, novel in zip(
        ("textures", "colours", "shapes"), pools["base"], pools["novel"], strict=True
    ):
        assert base, f"{task} base environments have no {name}"
        assert not base & novel, (
            f"{task} base and novel share {name}: {sorted(map(str, base & novel))[:5]}"
        )


@pytest.mark.parametrize("task", ALL_TASKS)
def test_environments_are_distinct_and_deterministic(task):
    cls = aed_tasks.get_task(task)
    for split in ("base", "novel"):
        envs = cls.get_catalogue(split)
        assert len(set(map(repr, envs))) == len(envs), f"{task} {split} repeats an environment"
        assert cls.make_environment(split, 0) == envs[0]


# --- splits that differ to the eye -------------------------------------------------------

MIN_DELTA_E = 15.0  # CIE76; about 2.3 is a just-noticeable difference, 15 reads as another colour
MIN_PROFILE_DISTANCE = 0.05  # Hausdorff distance between revolved outlines, in the unit profile box


def srgb_to_lab(rgb) -> np.ndarray:
    """CIELAB (D65) of sRGB colours in [0, 1], shape (..., 3)."""
    c = np.asarray(rgb, dtype=float)[..., :3]
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    to_xyz = np.array(
        [
            [0.4124564, 0.3575761, 0.1804375],
            [0.2126729, 0.7151522, 0.0721750],
            [0.0193339, 0.1191920, 0.9503041],
        ]
    )
    xyz = linear @ to_xyz.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack(
        [116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])],
        axis=-1,
    )


def min_delta_e(a, b) -> float:
    """The smallest CIE76 colour difference between any colour of `a` and any of `b`."""
    lab_a, lab_b = (
        srgb_to_lab(np.asarray(a, float).reshape(-1, 3)),
        srgb_to_lab(np.asarray(b, float).reshape(-1, 3)),
    )
    return float(np.linalg.norm(lab_a[:, None] - lab_b[None], axis=-1).min())


def test_delta_e_matches_reference_values():
    assert srgb_to_lab([1.0, 1.0, 1.0]) == pytest.approx([100.0, 0.0, 0.0], abs=0.01)
    assert srgb_to_lab([1.0, 0.0, 0.0]) == pytest.approx([53.24, 80.09, 67.20], abs=0.05)
    assert min_delta_e([[0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]]) == pytest.approx(100.0, abs=0.01)


def texture_colours(split: str) -> np.ndarray:
    return np.array([c for pair in TEXTURE_PALETTES[split] for c in pair], float) / 255


def test_palettes_of_the_splits_differ_to_the_eye():
    base, novel = (np.array(OBJECT_COLOURS[s])[:, :3] for s in ("base", "novel"))
    assert min_delta_e(base, novel) >= MIN_DELTA_E, "object colours"
    assert min_delta_e(texture_colours("base"), texture_colours("novel")) >= MIN_DELTA_E, (
        "texture colours"
    )
    for split, colours in (("base", base), ("novel", novel)):
        tint = [DEMONSTRATOR_TINT[:3]]
        assert min_delta_e(tint, colours) >= MIN_DELTA_E, (
            f"demonstrator tint vs {split} object colours"
        )
        assert min_delta_e(tint, texture_colours(split)) >= MIN_DELTA_E, (
            f"demonstrator tint vs {split} textures"
        )


@functools.cache
def mean_texture_colour(name: str) -> np.ndarray:
    image = cv2.imread(str(texture_path(name)), cv2.IMREAD_COLOR)[..., ::-1]
    return image.reshape(-1, 3).mean(axis=0) / 255


def background_colours(task: str, split: str) -> np.ndarray:
    """What the eye sees of each floor, wall and table: base colour times mean texture colour."""
    out = []
    for env in aed_tasks.get_task(task).get_catalogue(split):
        for material in (env.floor, env.wall, env.table):
            texture = mean_texture_colour(material.texture) if material.texture else 1.0
            out.append(np.asarray(material.colour[:3]) * texture)
    return np.array(out)


def test_backgrounds_of_the_splits_differ_to_the_eye():
    """Floors, walls and tables of every task (Factory Packing's halls included), across tasks."""
    base = np.concatenate([background_colours(t, "base") for t in ALL_TASKS])
    novel = np.concatenate([background_colours(t, "novel") for t in ALL_TASKS])
    assert min_delta_e(base, novel) >= MIN_DELTA_E


def role_shapes(task: str) -> dict[str, dict[str, set[str]]]:
    """{object role: {split: shapes}}, distractors as one role."""
    roles: dict[str, dict[str, set[str]]] = {}
    for split in ("base", "novel"):
        for env in aed_tasks.get_task(task).get_catalogue(split):
            pairs = [(k, o.shape) for k, o in env.objects.items()] + [
                ("distractor", d.shape) for d in env.distractors
            ]
            for role, shape in pairs:
                roles.setdefault(role, {"base": set(), "novel": set()})[split].add(shape)
    return roles


def dense_outline(outline, samples: int = 200) -> np.ndarray:
    points = np.asarray(outline, float)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], samples)
    return np.stack([np.interp(s, arc, points[:, 0]), np.interp(s, arc, points[:, 1])], axis=1)


def profile_distance(a: str, b: str) -> float:
    """Hausdorff distance between two revolved outlines (sections ignored: an octagon is no
    disguise)."""
    pa, pb = dense_outline(MESH_PROFILES[a]["outline"]), dense_outline(MESH_PROFILES[b]["outline"])
    d = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
    return float(max(d.min(axis=0).max(), d.min(axis=1).max()))


@pytest.mark.parametrize("task", ALL_TASKS)
def test_no_shape_generator_serves_both_splits(task):
    for role, shapes in role_shapes(task).items():
        missing = (shapes["base"] | shapes["novel"]) - set(SHAPE_GENERATORS)
        assert not missing, (
            f"{task} {role}: shapes without a SHAPE_GENERATORS entry: {sorted(missing)}"
        )
        generators = {s: {SHAPE_GENERATORS[x] for x in shapes[s]} for s in ("base", "novel")}
        shared = generators["base"] & generators["novel"]
        assert not shared, f"{task} {role}: base and novel shapes share generators {sorted(shared)}"
        for b, n in itertools.product(sorted(shapes["base"]), sorted(shapes["novel"])):
            if b in MESH_PROFILES and n in MESH_PROFILES:
                distance = profile_distance(b, n)
                assert distance >= MIN_PROFILE_DISTANCE, (
                    f"{task} {role}: {b} and {n} profiles differ by {distance:.3f}"
                )


def test_profile_distance_sees_a_faceted_copy():
    """The check the shape test relies on: same outline, other sections, counts as the same
    shape."""
    assert profile_distance("coaster_hexagon", "coaster_oval") < MIN_PROFILE_DISTANCE
    assert profile_distance("glass_tumbler", "glass_octagonal") >= MIN_PROFILE_DISTANCE

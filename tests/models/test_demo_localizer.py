"""The demonstration-conditioned localizer probe (`scripts/demo_localizer.py`): trained on some
environments, it finds a square of a colour it never saw from the demonstrations that press it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from tests.helpers import load_script, recorded_episode, write_synthetic_collection

H, W = 64, 80
FOCAL, HEIGHT_M = 60.0, 1.0  # a camera looking straight down from 1 m
INTRINSIC = np.array([[FOCAL, 0, W / 2], [0, FOCAL, H / 2], [0, 0, 1]], np.float32)
EXTRINSIC = np.array([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, HEIGHT_M]], np.float32)
TOP_M = 0.02  # the squares' height


def pixel(x: float, y: float) -> tuple[int, int]:
    return int(FOCAL * x + W / 2), int(-FOCAL * y + H / 2)


def scene(env_index: int, split: str):
    """Per environment, the target square's colour and a distractor's (held-out environments
    get colours the training ones never show)."""
    hue = np.random.default_rng([env_index, split == "novel"]).uniform(0.3, 1.0, 3)
    target = (255 * hue).astype(np.uint8)
    distractor = (255 * (1.0 - hue) * 0.8).astype(np.uint8)
    return target, distractor


def make_maker(split: str):
    def synthetic(role: str, env_index: int, seed: int, steps: int):
        rng = np.random.default_rng(seed)
        (bx, by), (dx, dy) = rng.uniform([-0.2, -0.15], [0.2, 0.15], (2, 2))
        target, distractor = scene(env_index, split)
        rgb = np.full((steps + 1, H, W, 3), 40, np.uint8)
        depth = np.full((steps + 1, H, W, 1), 1000, np.int16)
        for (x, y), colour in (((dx, dy), distractor), ((bx, by), target)):
            u, v = pixel(x, y)
            rgb[:, v - 3 : v + 3, u - 3 : u + 3] = colour
            depth[:, v - 3 : v + 3, u - 3 : u + 3] = int(1000 * (HEIGHT_M - TOP_M))
        t = np.linspace(0.0, 1.0, steps + 1)[:, None]
        tcp = np.zeros((steps + 1, 7), np.float32)
        tcp[:, :3] = (1 - t) * np.array([0.0, 0.0, 0.3]) + t * np.array([bx, by, TOP_M])
        tcp[:, 3] = 1.0
        button = np.zeros((steps + 1, 15), np.float32)
        button[:, :3] = bx, by, 0.0
        states = {"articulations": {"button": button}}
        actions = np.zeros((steps, 4), np.float32)
        camera = {
            "intrinsic_cv": np.tile(INTRINSIC, (steps + 1, 1, 1)),
            "extrinsic_cv": np.tile(EXTRINSIC, (steps + 1, 1, 1)),
        }
        return recorded_episode(
            "PressButton", role, env_index, seed, rgb, depth, actions, tcp, states,
            split=split, sensor_param=camera,
        )  # fmt: skip

    return synthetic


@pytest.fixture(scope="module")
def collections(tmp_path_factory):
    root = tmp_path_factory.mktemp("localizer")
    base = write_synthetic_collection(
        root / "base", {"demo": 3, "agent_success": 3}, envs=tuple(range(8)), steps=4,
        step_increment=1, make_episode=make_maker("base"), demo_seed_offset=50,
    )  # fmt: skip
    novel = write_synthetic_collection(
        root / "novel", {"demo": 4}, envs=(0, 1, 2), steps=4, step_increment=1,
        make_episode=make_maker("novel"),
    )  # fmt: skip
    return base, novel


def test_geometry_round_trips():
    probe = load_script("demo_localizer")
    point = np.array([[0.1, -0.05, 0.0]])  # on the table, 1 m below the camera
    uv = probe.project(point, INTRINSIC, EXTRINSIC)
    assert np.allclose(uv, [[W / 2 + 6.0, H / 2 + 3.0]])
    depth = np.array([HEIGHT_M])
    assert np.allclose(probe.unproject(uv, depth, INTRINSIC, EXTRINSIC), point, atol=1e-6)
    logits = torch.full((4, 5), -10.0)
    logits[2, 3] = 10.0
    assert np.allclose(probe.refined_pixel(logits), [3.5 * probe.STRIDE, 2.5 * probe.STRIDE])


def test_colour_jitter_recolours_rgb_and_keeps_depth():
    """Each sequence gets one recolouring: its RGB channels permuted and scaled (or made grey),
    the same on all its frames; depth untouched; strength 0 is the identity."""
    colour_jitter = load_script("demo_localizer").colour_jitter
    colour = torch.tensor([0.8, 0.4, 0.1])
    frames = torch.zeros(64, 3, 4, 8, 8)
    frames[:, :, :3] = colour.view(1, 1, 3, 1, 1)
    frames[:, :, 3] = torch.rand(64, 3, 8, 8)
    generator = torch.Generator().manual_seed(0)
    assert colour_jitter(frames, 0.0, generator) is frames
    out = colour_jitter(frames, 0.3, generator)
    assert torch.equal(out[:, :, 3], frames[:, :, 3])
    rgb = out[:, :, :3]
    assert torch.equal(rgb[:, :1].expand_as(rgb), rgb)  # one draw per sequence, every frame
    rgb = out[:, 0, :3, 0, 0]
    grey = (rgb[:, 0] == rgb[:, 1]) & (rgb[:, 1] == rgb[:, 2])
    assert 0 < grey.sum() < 64
    brightest = rgb[~grey].argmax(dim=1)
    assert len(set(brightest.tolist())) > 1  # the red channel moved
    for row in rgb[~grey]:  # each a permutation of the colour, scaled by gains in [0.7, 1.3]
        ratios = [
            row / colour[list(p)]
            for p in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))
        ]
        assert any(((r >= 0.7 - 1e-6) & (r <= 1.3 + 1e-6)).all() for r in ratios), row


def test_localizer_finds_an_unseen_colour_from_the_demonstrations(collections, tmp_path):
    probe = load_script("demo_localizer")
    base, novel = collections
    config = probe.Config(
        data=base, novel=novel, steps=150, batch=8, frames_per_episode=3, colour=0.0,
        checkpoint=tmp_path / "map.pt", out=tmp_path / "result.json",
    )  # fmt: skip
    result = probe.main(config)
    errors = result["novel_demo_xy_error_cm"]
    assert errors["localizer"]["n"] == errors["mean_guess"]["n"] == 12
    low, high = errors["localizer"]["mean_95"]
    assert (
        low <= errors["localizer"]["mean"] <= high and errors["localizer"]["demonstrations"] == 12
    )
    first, last = result["loss_first_last_tenth"]
    assert last < 0.5 * first
    assert errors["localizer"]["mean"] < 0.5 * errors["mean_guess"]["mean"], errors
    assert json.loads((tmp_path / "result.json").read_text()) == result
    again = probe.main(config)  # the saved map is loaded, not retrained
    assert again["novel_demo_xy_error_cm"] == errors
    assert again["trained_with"] == result["trained_with"]
    every = probe.main(dataclasses.replace(config, every=2, out=None))["novel_demo_xy_error_cm"]
    assert every["localizer"]["n"] == every["mean_guess"]["n"] == 3 * (3 + 3 + 4 + 4)

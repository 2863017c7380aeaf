"""Subcommands of `aed` run as commands (the others are run in the test modules of their
stage): what `aed models` lists and what `aed render` writes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2

AED = str(Path(sys.executable).with_name("aed"))


def test_models_lists_every_policy_and_detector():
    from aed_models.detectors import DETECTORS
    from aed_models.policies import POLICIES

    result = subprocess.run([AED, "models"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    for name in (*POLICIES, *DETECTORS):
        assert name in result.stdout, name


def test_render_writes_each_split_and_a_contact_sheet(tmp_path):
    result = subprocess.run(
        [AED, "render", "--tasks", "PressButton", "--no-large", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    images = sorted(p.name for p in tmp_path.glob("*.png"))
    assert {"PressButton_base_0.png", "PressButton_novel_0.png"} <= set(images), images
    for name in ("PressButton_base_0.png", "PressButton_novel_0.png"):
        image = cv2.imread(str(tmp_path / name))
        assert image.shape == (120, 160, 3) and image.std() > 0  # rendered, not blank

"""The foundation: rendering works on this machine, the CLI runs, the code is ruff clean."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (registers PickCube-v1)

import aed_tasks
from aed_eval.doctor import rendering_device

ROOT = Path(__file__).resolve().parent.parent
AED = str(Path(sys.executable).with_name("aed"))


def test_sapien_finds_a_rendering_device():
    assert rendering_device() is not None, "run `aed doctor`: SAPIEN finds no Vulkan device"


def test_a_maniskill_env_renders_a_non_blank_rgbd_frame():
    env = gym.make("PickCube-v1", obs_mode="rgbd", sensor_configs={"width": 160, "height": 120})
    obs, _ = env.reset(seed=0)
    camera = obs["sensor_data"]["base_camera"]
    rgb, depth = camera["rgb"][0].numpy(), camera["depth"][0].numpy()
    env.close()
    assert rgb.shape == (120, 160, 3) and rgb.std() > 5
    assert depth.shape == (120, 160, 1) and depth.max() > 0


def test_aed_doctor_reports_versions_and_the_device():
    result = subprocess.run([AED, "doctor"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "mani-skill" in result.stdout and "rendering" in result.stdout
    assert "NO DEVICE" not in result.stdout


def test_aed_envs_lists_every_registered_id():
    result = subprocess.run([AED, "envs"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == aed_tasks.registered_ids()
    assert "AED-PickPlace-novel" in result.stdout.split()


def test_aed_rejects_an_unknown_subcommand():
    result = subprocess.run([AED, "juggle"], capture_output=True, text=True, timeout=120)
    assert result.returncode != 0


def test_setup_rerun_is_a_quick_no_op():
    result = subprocess.run(["bash", "scripts/setup.sh"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "ready" in result.stderr


def test_ruff_is_clean():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent))
    assert ruff, "ruff is a dev dependency: pip install -e .[dev]"
    result = subprocess.run([ruff, "check", "."], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout


def test_bad_input_is_one_named_error_line():
    result = subprocess.run([AED, "collect", "--task", "Juggle"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "unknown task 'Juggle'" in result.stderr
    assert "Traceback" not in result.stderr
    result = subprocess.run([AED, "data-info", "/nonexistent/aed"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "/nonexistent/aed: no such collection folder" in result.stderr

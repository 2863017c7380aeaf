"""The foundation: rendering works on this machine, the CLI runs, the code is ruff clean."""

from __future__ import annotations

import os
import re
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
    result = subprocess.run(
        ["bash", "scripts/setup.sh"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
    assert "ready" in result.stderr


def _setup_sh(call: str, **env: str) -> subprocess.CompletedProcess:
    """Source scripts/setup.sh (functions only) and run `call`; apt-get is stubbed out."""
    script = f"source scripts/setup.sh; set +e; apt-get() {{ echo APT-GET-RAN; return 1; }}; {call}"
    return subprocess.run(
        ["bash", "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **env},
    )


def test_setup_takes_the_mirror_from_the_apt_sources_only(tmp_path):
    (tmp_path / "sources.list.d").mkdir()
    (tmp_path / "sources.list.d" / "distro.sources").write_text(
        "Types: deb\n# URIs: http://commented.example/debian\nURIs: http://off.example/debian\n"
        "Suites: bookworm\nEnabled: no\n\n"
        "Types: deb-src deb\nURIs: https://mirror.example/debian http://second.example/debian\n"
        "Suites: bookworm bookworm-updates\nComponents: main\n\n"
        "Types: deb\nURIs: http://security.example/debian-security\nSuites: bookworm-security\n"
    )
    (tmp_path / "sources.list.d" / "old.sources.disabled").write_text(
        "Types: deb\nURIs: http://x/\nSuites: trixie\n"
    )
    (tmp_path / "sources.list").write_text(
        "# deb http://commented.example/debian bookworm-backports main\n"
        "deb-src http://src.example/debian bookworm-backports main\n"
        "deb [arch=amd64 signed-by=/usr/share/keyrings/k.gpg] http://backports.example/debian "
        "bookworm-backports main\n"
    )
    found = {}
    for suite in ("bookworm", "bookworm-backports", "bookworm-security", "trixie"):
        result = _setup_sh(f"apt_source_for_suite {suite} {tmp_path}")
        assert result.returncode == 0, result.stderr
        found[suite] = result.stdout.strip()
    assert found == {
        "bookworm": "https://mirror.example/debian",
        "bookworm-backports": "http://backports.example/debian",
        "bookworm-security": "http://security.example/debian-security",
        "trixie": "",
    }


def test_no_package_mirror_is_written_out():
    from aed_eval.doctor import VULKAN_HELP

    mirror = re.compile(r"(https?|ftp)://\S*(debian|ubuntu)")
    for path in ("README.md", "scripts/setup.sh", "aed_eval/doctor.py"):
        assert not mirror.search((ROOT / path).read_text()), f"{path} names a package mirror"
    assert "bookworm-backports suite" in VULKAN_HELP


def test_setup_without_a_configured_mirror_says_what_to_add(tmp_path):
    result = _setup_sh("install_vulkan_driver", AED_APT_ROOT=str(tmp_path))
    assert result.returncode == 1 and "APT-GET-RAN" not in result.stdout
    assert "bookworm-backports suite" in result.stderr and "http" not in result.stderr


def test_ruff_is_clean():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent))
    assert ruff, "ruff is a dev dependency: pip install -e .[dev]"
    result = subprocess.run(
        [ruff, "check", "."], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout


def test_bad_input_is_one_named_error_line():
    result = subprocess.run(
        [AED, "collect", "--task", "Juggle"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2 and "unknown task 'Juggle'" in result.stderr
    assert "Traceback" not in result.stderr
    result = subprocess.run(
        [AED, "data-info", "/nonexistent/aed"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2 and "/nonexistent/aed: no such collection folder" in result.stderr

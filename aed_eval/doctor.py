"""`aed doctor` and `aed envs`: is this machine ready, and what is registered."""

from __future__ import annotations

import importlib.metadata as md
import platform

VULKAN_HELP = (
    "SAPIEN found no Vulkan rendering device. On Debian bookworm without a GPU, install Mesa's\n"
    "lavapipe >= 24.3 from bookworm-backports (the distribution's Mesa 22.3 lacks\n"
    "VK_KHR_external_semaphore_fd): add the bookworm-backports suite (component main) of the\n"
    "Debian mirror your apt sources already use, then\n"
    "  apt-get update && apt-get install -y -t bookworm-backports mesa-vulkan-drivers libvulkan1\n"
    "or simply run scripts/setup.sh, which does exactly this with the mirror it finds in your\n"
    "apt sources. On a GPU machine, install the vendor's Vulkan driver (e.g. NVIDIA's\n"
    "libnvidia-gl) instead."
)

PACKAGES = (
    "aed-toolkit",
    "mani-skill",
    "sapien",
    "mplib",
    "numpy",
    "torch",
    "gymnasium",
    "opencv-python-headless",
)


def rendering_device() -> str | None:
    """Name of the device SAPIEN renders with, or None when it finds none."""
    try:
        import sapien

        system = sapien.render.RenderSystem()
        return str(system.device.name)
    except Exception:  # SAPIEN raises a bare RuntimeError when Vulkan has no device
        return None


def doctor() -> int:
    """Print versions and whether SAPIEN finds a rendering device; say what to install if not."""
    print(f"python       {platform.python_version()} ({platform.machine()})")
    for name in PACKAGES:
        try:
            version = md.version(name)
        except md.PackageNotFoundError:
            version = "not installed"
        print(f"{name:<12} {version}")
    device = rendering_device()
    if device is None:
        print("rendering    NO DEVICE\n\n" + VULKAN_HELP)
        return 1
    print(f"rendering    {device}")
    return 0


def list_envs() -> int:
    """List the registered AED environment ids, one a line."""
    import aed_tasks

    for env_id in aed_tasks.registered_ids():
        print(env_id)
    return 0

"""Camera shaders: SAPIEN's `minimal` pack with a shadow filter cheap enough for CPU rendering.

SAPIEN filters directional shadows with a 25-tap percentage-closer filter (each tap a
`textureGather` of four depths). On Mesa's lavapipe, which shades on the CPU, that alone
costs about 13 ms of a 60 ms step at 160x120 (measured: PickCube-v1 goes from 43 to 59 ms
with its shadow on). The `aed_minimal` pack is the installed `minimal` pack with a 4-tap
kernel at half-texel offsets: shadow edges stay soft over about three shadow-map texels,
and the step costs about 10 ms less. Nothing else of the shaders changes (colour, depth
and segmentation are the same textures in the same formats).

The pack is derived from the installed SAPIEN at first use and cached per SAPIEN version,
so it follows upgrades and nothing of SAPIEN's is copied into this repository.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from functools import cache
from importlib.metadata import version
from pathlib import Path
from typing import Any

PACK_NAME = "aed_minimal"
SOURCE_PACK = "minimal"
PCF_25 = "const int PCF_SampleCount = 25;"
PCF_4 = """const int PCF_SampleCount = 4;
vec2 PCF_Samples[PCF_SampleCount] = {
  {-0.5, -0.5}, {0.5, -0.5}, {-0.5, 0.5}, {0.5, 0.5}
};
"""
# picture formats of the `minimal` pack (ManiSkill sets them only for packs named "minimal")
PICTURE_FORMATS = {
    "Color": "r8g8b8a8unorm",
    "ColorRaw": "r8g8b8a8unorm",
    "PositionSegmentation": "r16g16b16a16sint",
}


def cache_root() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "aed" / "shaders"


@cache
def shader_pack_dir() -> Path:
    """`<cache>/sapien-<version>/aed_minimal`, written (atomically) on first use."""
    import sapien

    root = cache_root() / f"sapien-{version('sapien')}"
    pack = root / PACK_NAME
    if (pack / "gbuffer.frag").exists():
        return pack
    source = Path(sapien.__file__).parent / "vulkan_shader"
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=root, prefix=".build-"))
    try:
        shutil.copytree(source / SOURCE_PACK, staging / PACK_NAME)
        shutil.copytree(source / "common", staging / "common")
        shadow = staging / "common" / "shadow.glsl"
        text = shadow.read_text()
        start, end = text.find(PCF_25), text.find("float ShadowMapPCF(")
        if start < 0 or end < 0:
            raise RuntimeError(
                f"{source / 'common' / 'shadow.glsl'}: no 25-tap PCF kernel to replace "
                "(SAPIEN changed?)"
            )
        shadow.write_text(text[:start] + PCF_4 + "\n" + text[end:])
        for name in ("common", PACK_NAME):  # the pack includes ../common: both move in together
            target = root / name
            try:
                os.replace(staging / name, target)
            except OSError:  # another process was first: its copy is the same
                if not target.exists():
                    raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return pack


def camera_shader_config() -> Any:
    """ManiSkill's `minimal` shader config, pointed at the `aed_minimal` pack."""
    from mani_skill.render.shaders import PREBUILT_SHADER_CONFIGS

    return dataclasses.replace(
        PREBUILT_SHADER_CONFIGS[SOURCE_PACK], shader_pack=str(shader_pack_dir())
    )


def use_minimal_picture_formats() -> None:
    """Set the picture formats the `minimal` textures are read with (a SAPIEN global)."""
    import sapien

    for name, fmt in PICTURE_FORMATS.items():
        sapien.render.set_picture_format(name, fmt)

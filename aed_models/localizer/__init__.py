"""The demonstration-conditioned target localizer: where, in this frame, the demonstrations'
stages end.

    localizer = load_localizer("runs/PressButton/localizer/localizer.pt")
    queries = localizer.queries(first_frames, stage_points)  # from a few demonstrations
    points = localizer.locate(frames, queries)               # (N, K, 3) world points

A fully convolutional map gives every cell (4 x 4 pixels under `mini`) a unit feature. A
demonstration's query for stage k is the feature, in its first frame, under the point where its
TCP ended stage k (projected with the fixed camera); in a new frame of the same environment the
cell most like the query is where stage k will end, lifted to 3-d with the frame's depth, or,
where that depth is of a surface behind the target, at the height the demonstrations ended
the stage. Trained
on base environments to match across episodes under a shared random recolouring, it matches
by appearance, which is what carries to the novel split's unseen objects. Under `mini` the
policies read the located points (offsets from the TCP) beside their features.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from aed_models.localizer.configuration_localizer import LocalizerConfig, LocalizerRecipe

if TYPE_CHECKING:
    from aed_models.localizer.modeling_localizer import TargetLocalizer

FAMILY = "localizer"
NAME = "demo_matching"


def load_localizer(path: Path | str, map_location: str = "cpu") -> TargetLocalizer:
    """A trained localizer from its checkpoint, in eval mode (its `sha256` set)."""
    from aed_models.checkpoint import load_checkpoint
    from aed_models.localizer.modeling_localizer import TargetLocalizer

    ckpt = load_checkpoint(path, family=FAMILY, name=NAME, map_location=map_location)
    localizer = TargetLocalizer(LocalizerConfig.from_dict(ckpt.config))
    localizer.load_state_dict(ckpt.state_dict)
    localizer.sha256 = ckpt.sha256
    return localizer.eval()


__all__ = ["FAMILY", "NAME", "LocalizerConfig", "LocalizerRecipe", "load_localizer"]

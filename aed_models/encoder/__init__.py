"""The scene encoder: a visual head trained once per task to say where things are, then frozen.

    encoder = load_encoder("runs/PressButton/encoder/encoder.pt")
    features, state = encoder(frames)        # (N, 256) features, (N, D) standardised state

Under `mini` every policy's visual head is this encoder, frozen, and its per-frame features
are computed once per collection (`aed_models.train.frame_features`): the policies then train
on cached features, not images.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from aed_models.encoder.configuration_encoder import EncoderConfig, EncoderRecipe

if TYPE_CHECKING:
    from aed_models.encoder.modeling_encoder import SceneEncoder

FAMILY = "encoder"
NAME = "scene"


def load_encoder(path: Path | str, map_location: str = "cpu") -> SceneEncoder:
    """A trained scene encoder from its checkpoint, in eval mode."""
    from aed_models.checkpoint import load_checkpoint
    from aed_models.encoder.modeling_encoder import SceneEncoder

    ckpt = load_checkpoint(path, family=FAMILY, name=NAME, map_location=map_location)
    encoder = SceneEncoder(EncoderConfig.from_dict(ckpt.config))
    encoder.load_state_dict(ckpt.state_dict)
    encoder.sha256 = ckpt.sha256
    return encoder.eval()


__all__ = ["FAMILY", "NAME", "EncoderConfig", "EncoderRecipe", "load_encoder"]

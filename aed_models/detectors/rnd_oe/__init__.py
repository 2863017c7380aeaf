"""RND-OE: failure-free random network distillation on policy features."""

from aed_models.detectors.rnd_oe.configuration_rnd_oe import RNDOEConfig

__all__ = ["RNDOEConfig"]

"""DCTED: DCT-style transformer baseline."""

from aed_models.detectors.dct_ed.configuration_dct_ed import DCTEDConfig

__all__ = ["DCTEDConfig"]

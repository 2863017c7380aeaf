"""SVDDED: deep one-class baseline centred on demonstrations."""

from aed_models.detectors.svdd_ed.configuration_svdd_ed import SVDDEDConfig

__all__ = ["SVDDEDConfig"]

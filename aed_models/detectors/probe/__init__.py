"""PrObe: the paper's pattern observer on policy features."""

from aed_models.detectors.probe.configuration_probe import ProbeConfig

__all__ = ["ProbeConfig"]

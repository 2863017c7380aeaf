"""TaskEmbED: single-frame baseline with a NaiveDC task embedding."""

from aed_models.detectors.taskemb_ed.configuration_taskemb_ed import TaskEmbEDConfig

__all__ = ["TaskEmbEDConfig"]

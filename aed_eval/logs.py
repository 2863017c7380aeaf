"""Logging set-up of the command line, scripts and tests (library code only logs)."""

from __future__ import annotations

import logging

MANISKILL_LOGGER = "mani_skill "  # sic: ManiSkill names its logger with a trailing space


class _AtLeast(logging.Filter):
    def __init__(self, level: int):
        super().__init__()
        self.level = level

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= self.level


def quiet_maniskill(level: int = logging.ERROR) -> None:
    """Drop ManiSkill's records below `level` (e.g. "no CUDA device" on CPU machines).

    A filter, not a level: ManiSkill resets its logger's level when it is imported, so this
    works before or after that import. Calling it again replaces the threshold.
    """
    logger = logging.getLogger(MANISKILL_LOGGER)
    for old in [f for f in logger.filters if isinstance(f, _AtLeast)]:
        logger.removeFilter(old)
    logger.addFilter(_AtLeast(level))


def setup_logging(level: int = logging.INFO) -> None:
    """Plain `LEVEL name: message` lines on stderr; ManiSkill's warnings silenced."""
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    quiet_maniskill()

"""Checks of names that CLI configs share: a bad one is a ValueError naming it (`aed` exits 2)."""

from __future__ import annotations

from collections.abc import Iterable


def task_class(name: str) -> type:
    """The registered task class of `name` (any spelling `aed_tasks.get_task` accepts)."""
    import aed_tasks

    try:
        return aed_tasks.get_task(name)
    except KeyError as e:
        raise ValueError(f"task={name!r}: {e.args[0]}") from None


def check_detectors(names: Iterable[str]) -> None:
    """Every name is a registered detector."""
    from aed_models.detectors import DETECTORS

    unknown = [d for d in names if d not in DETECTORS]
    if unknown:
        raise ValueError(f"detectors={unknown}: known {sorted(DETECTORS)}")

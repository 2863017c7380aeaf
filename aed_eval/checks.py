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


def check_camera(name: str) -> str:
    """`name` is one of the tasks' cameras (`aed_tasks.base_env.CAMERAS`)."""
    from aed_tasks.base_env import CAMERAS

    if name not in CAMERAS:
        raise ValueError(f"camera={name!r}: known {sorted(CAMERAS)}")
    return name


def check_detectors(names: Iterable[str]) -> None:
    """Every name is a registered detector."""
    from aed_models.detectors import DETECTORS

    unknown = [d for d in names if d not in DETECTORS]
    if unknown:
        raise ValueError(f"detectors={unknown}: known {sorted(DETECTORS)}")


def trained_envs(label: str, extra: dict | None) -> tuple[str, set[int]]:
    """(split, environment indices) a model trained on, from its checkpoint's `extra`.

    A checkpoint never trained (no `train_config`) trained on nothing; a trained one that does
    not record its environments (written before they were recorded) is refused.
    """
    extra = extra or {}
    if "train_envs" in extra:
        return str(extra.get("train_split", "base")), {int(e) for e in extra["train_envs"]}
    if "train_config" in extra:
        raise ValueError(
            f"{label}: its checkpoint does not record its training environments; retrain it"
        )
    return "base", set()


def check_held_out(
    models: dict[str, dict | None], split: str, envs: Iterable[int], what: str, allow: bool = False
) -> dict[str, list[int]]:
    """Refuse to score models on environments they trained on: a ValueError in one line naming
    the model and the overlap, unless `allow` (a diagnostic); returns the overlaps either way.

    `models` maps a label (e.g. "policy dct", "detector probe") to its checkpoint `extra`.
    """
    envs = {int(e) for e in envs}
    overlaps = {}
    for label, extra in models.items():
        trained_split, trained = trained_envs(label, extra)
        common = sorted(trained & envs) if trained_split == split else []
        if common:
            overlaps[label] = common
    if overlaps and not allow:
        label, common = next(iter(overlaps.items()))
        more = f" (and {len(overlaps) - 1} more models)" if len(overlaps) > 1 else ""
        raise ValueError(
            f"{what}: {label} trained on {split} environments {common}{more}; "
            "score it on environments no compared model trained on, or pass --allow-trained-envs "
            "for a diagnostic"
        )
    return overlaps

"""The paper's published numbers, where its text gives them, in this project's names.

Only the tables of the paper's text are here: the policies' success rates, the demonstration
quality and viewpoint experiments and the error-correction pilot. The main results, the rollout
augmentation and component ablations and the stability runs are figures in the paper, whose
numbers its text does not give. The results records copy what they stand beside (a record's
table is rendered from the record alone) and say which of the paper's tables it is from.

Success rates are in percent: the mean over the novel environments and its standard deviation
across them (20 rollouts an environment), the paper's statistic.
"""

from __future__ import annotations

from typing import Any

POLICY_SUCCESS: dict[str, dict[str, tuple[float, float]]] = {
    "CloseDrawer": {"naive_dc": (91.11, 20.85), "dct": (80.56, 26.71), "scan": (88.33, 13.94)},
    "PressButton": {"naive_dc": (51.94, 18.79), "dct": (80.56, 11.65), "scan": (75.56, 12.68)},
    "PickPlace": {"naive_dc": (55.00, 24.98), "dct": (64.05, 19.77), "scan": (71.19, 15.38)},
    "MoveGlassCup": {"naive_dc": (42.25, 34.04), "dct": (88.00, 14.87), "scan": (58.25, 20.33)},
    "OrganizeTable": {"naive_dc": (12.20, 13.93), "dct": (79.00, 9.27), "scan": (66.60, 23.18)},
    "BackToBox": {"naive_dc": (8.89, 9.21), "dct": (29.17, 9.46), "scan": (58.89, 10.87)},
    "FactoryPacking": {"naive_dc": (45.42, 30.92), "dct": (88.75, 7.11), "scan": (63.75, 33.11)},
}
"""Appendix table "FSI policy performance": success rate in novel environments (mean, std) %."""

_DETECTORS = ("svdd_ed", "taskemb_ed", "lstm_ed", "dct_ed", "probe")


def _row(success: tuple[float, float], *scores: float) -> dict[str, Any]:
    return {"success_rate": success, "detectors": dict(zip(_DETECTORS, scores, strict=True))}


DEMO_QUALITY: dict[str, dict[str, dict[str, Any]]] = {
    "naive_dc": {
        "all optimal": _row((51.94, 18.79), 0.6956, 0.7280, 0.7051, 0.8405, 0.8851),
        "2 sub-optimal": _row((50.83, 18.50), 0.6861, 0.7407, 0.7168, 0.8832, 0.9059),
        "all sub-optimal": _row((51.67, 17.24), 0.6414, 0.7276, 0.7044, 0.8446, 0.8930),
    },
    "dct": {
        "all optimal": _row((80.56, 11.65), 0.3789, 0.3597, 0.4468, 0.5734, 0.7474),
        "2 sub-optimal": _row((78.61, 14.02), 0.3908, 0.3811, 0.4606, 0.6019, 0.7530),
        "all sub-optimal": _row((77.22, 14.16), 0.3899, 0.4051, 0.4718, 0.5341, 0.7588),
    },
    "scan": {
        "all optimal": _row((75.56, 12.68), 0.4653, 0.4657, 0.4487, 0.6757, 0.7505),
        "2 sub-optimal": _row((71.67, 11.18), 0.4985, 0.5165, 0.4979, 0.7467, 0.7804),
        "all sub-optimal": _row((69.72, 12.30), 0.4886, 0.5262, 0.5096, 0.7140, 0.7752),
    },
}
"""Appendix table "Demonstration quality experiment" (Press Button, AUPRC). The paper's middle
setting, "3 optimal & 2 sub", is this project's "2 sub-optimal"."""

VIEWPOINT: dict[str, dict[str, Any]] = {
    "front": _row((80.00, 10.80), 0.5694, 0.5465, 0.4929, 0.7501, 0.7498),
    "front_shift": _row((78.33, 11.18), 0.4821, 0.4959, 0.4667, 0.7056, 0.7225),
}
"""Appendix table "Viewpoint changes" (Press Button, DCT, AUROC; the policy's success rate from
its text). The paper's "original" and "shift" are this project's cameras `front` and
`front_shift`."""

ERROR_CORRECTION: dict[str, Any] = {
    "without": (80.56, 11.65),
    "detectors": {
        "taskemb_ed": (80.56, 11.65),
        "lstm_ed": (80.28, 11.60),
        "dct_ed": (71.67, 20.75),
        "probe": (82.22, 10.17),
    },
}
"""Table "Error correction results" (Press Button, DCT, threshold 0.9): success rate (mean, std) %
without correction and corrected at each detector's alarms (the paper leaves SVDDED out)."""

VARIANT_TABLES: dict[str, tuple[str, str, dict[str, dict[str, dict[str, Any]]]]] = {
    "demo_quality": ("auprc", 'appendix table "Demonstration quality experiment"', DEMO_QUALITY),
    "viewpoint": ("auroc", 'appendix table "Viewpoint changes"', {"dct": VIEWPOINT}),
}
"""The variant experiments the paper gives numbers for (on Press Button): the metric, where the
numbers are, and them by policy."""


def variant_numbers(experiment: str, task: str, policy: str) -> dict[str, Any] | None:
    """The paper's numbers for one (task, policy) of a variant experiment, keyed by this
    project's variant names; None where the paper's text gives none."""
    metric, source, by_policy = VARIANT_TABLES.get(experiment, (None, None, {}))
    if task != "PressButton" or policy not in by_policy:
        return None
    return {"metric": metric, "source": source, "variants": by_policy[policy]}


def correction_numbers(task: str, policy: str) -> dict[str, Any] | None:
    """The paper's error-correction pilot, for the (task, policy) it ran on; else None."""
    if (task, policy) != ("PressButton", "dct"):
        return None
    return {"source": 'table "Error correction results"', **ERROR_CORRECTION}


def format_rate(rate: tuple[float, float] | list[float]) -> str:
    """A success rate of the paper's, (mean, std) %, as its tables print it."""
    return "{:.2f} +- {:.2f}%".format(*rate)

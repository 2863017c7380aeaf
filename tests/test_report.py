"""`aed report`: the paper's summary rows rank the paper's five detectors only, over cases large
enough to rank; overlapping intervals at the top are marked."""

from __future__ import annotations

from aed_eval.report import build_report, summary_rows
from aed_eval.scoring import DETECTOR_NAMES, PAPER_DETECTORS


def cell(value: float, half: float = 0.05) -> dict:
    return {
        "auroc": value,
        "auroc_interval": [value - half, value + half],
        "auprc": value,
        "auprc_interval": [value - half, value + half],
        "roc": {"fpr": [0, 1], "tpr": [0, 1]},
        "calibrated": {},
    }


def case(
    policy: str,
    values: dict[str, float],
    successes: int = 10,
    failures: int = 10,
    half: float = 0.05,
) -> dict:
    lengths = {"success": {"median": 130}, "failure": {"median": 130}}
    return {
        "task": "PressButton",
        "policy": policy,
        "ending": "horizon",
        "endings": ["horizon"],
        "diagnostic": False,
        "detectors": {d: {"horizon": cell(values[d], half)} for d in DETECTOR_NAMES},
        "references": {r: {"horizon": cell(0.5, 0.2)} for r in ("time_only", "random")},
        "rollouts": {
            "count": successes + failures,
            "horizon": 130,
            "outcomes": {"horizon": {"successes": successes, "failures": failures}},
            "lengths": {"horizon": lengths},
            "success_rate": {
                "rate": 0.5,
                "interval": [0.3, 0.7],
                "successes": successes,
                "mean": 0.5,
                "std": 0.1,
                "num_envs": 4,
            },
        },
    }


def test_only_the_papers_five_are_ranked_and_small_cases_are_left_out():
    values = {
        "svdd_ed": 0.6,
        "taskemb_ed": 0.55,
        "lstm_ed": 0.7,
        "dct_ed": 0.65,
        "probe": 0.8,
        "rnd_oe": 0.95,
    }
    small = {**values, "svdd_ed": 0.99}  # would make svdd_ed Top-1 if a 3-success case ranked
    cases = [case("dct", values), case("scan", small, successes=3)]
    summary = summary_rows(cases, list(PAPER_DETECTORS), "auroc", "horizon")
    assert set(summary) == set(PAPER_DETECTORS)  # rnd_oe, the best here, stands outside
    assert (
        summary["probe"]["top1"] == 1
        and summary["svdd_ed"]["top1"] == 0
        and summary["probe"]["avg_rank"] == 1.0
    )
    report, text = build_report(cases, list(DETECTOR_NAMES))
    assert report["ranked"] == list(PAPER_DETECTORS)
    assert "| PressButton / scan ‡ |" in text and "| PressButton / dct |" in text
    assert "**0.800 [0.75, 0.85]**" in text and "every rollout runs the horizon" in text


def test_a_best_score_within_the_runner_ups_interval_is_marked():
    values = {
        "svdd_ed": 0.6,
        "taskemb_ed": 0.55,
        "lstm_ed": 0.78,
        "dct_ed": 0.65,
        "probe": 0.8,
        "rnd_oe": 0.5,
    }
    _, text = build_report([case("dct", values, half=0.05)], list(DETECTOR_NAMES))
    assert "**0.800 [0.75, 0.85]** ≈" in text
    values["lstm_ed"] = 0.6
    _, text = build_report([case("dct", values, half=0.05)], list(DETECTOR_NAMES))
    assert "**0.800 [0.75, 0.85]** |" in text

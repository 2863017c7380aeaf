"""Timing accuracy: every detector's score curve on a successful rollout, a failed one and a
labelled failure with its onset, for each (task, policy) evaluated under a profile.

Reads the evaluations `aed evaluate` (or `aed experiments`) wrote under `--runs` and writes one
results record per case, with its table and figure, under `results/<profile>/timing_accuracy/`
(`aed_eval.results.timing`; `aed results` re-renders them from the JSON):

    python scripts/timing_accuracy.py --profile mini --tasks PressButton --policies scan
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import tyro

from aed_eval.figures import CasesConfig, run_evaluated_cases


@dataclass
class Config(CasesConfig):
    calibration: str = "policy"
    """Which calibrated threshold: `policy` (the policy's own successes) or `expert`."""
    alpha: float = 0.1
    """The threshold's false-alarm rate."""


def main(cfg: Config) -> list[Path]:
    return run_evaluated_cases("timing_accuracy", cfg, calibration=cfg.calibration, alpha=cfg.alpha)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

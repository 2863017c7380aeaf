"""Success window: each detector's rollout-level AUROC over whole rollouts beside the same over
the frames up to each success's first success step, and how often a success's maximum score
comes after it (`aed_eval.results.success_window`).

Reads the evaluations and novel rollouts `aed experiments` wrote under `--runs` and writes one
record per case under `results/<profile>/success_window/` (`aed results` re-renders them):

    python scripts/success_window.py --profile mini --tasks OrganizeTable --policies scan
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import tyro

from aed_eval.figures import run_evaluated_cases
from aed_models.recipe import Profile, check_profile
from aed_tasks import PAPER_TASK_ORDER


@dataclass
class Config:
    profile: Profile = "mini"
    """The profile whose evaluations are read; results go to results/<profile>/."""
    runs: Path | None = None
    """Runs folder (default: runs/<profile>, where `aed experiments` writes)."""
    tasks: tuple[str, ...] = PAPER_TASK_ORDER
    policies: tuple[str, ...] = ("naive_dc", "dct", "scan")
    out: Path | None = None
    """Folder of the records (default: results/<profile>/success_window)."""

    def __post_init__(self) -> None:
        check_profile(self.profile)
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile


def main(cfg: Config) -> list[Path]:
    return run_evaluated_cases(
        "success_window", cfg.profile, cfg.runs, cfg.tasks, cfg.policies, cfg.out
    )


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

"""Success window: each detector's rollout-level AUROC over whole rollouts beside the same over
the frames up to each success's first success step, and how often a success's maximum score
comes after it (`aed_eval.results.success_window`).

Reads the evaluations and novel rollouts `aed experiments` wrote under `--runs` and writes one
record per case under `results/<profile>/success_window/` (`aed results` re-renders them):

    python scripts/success_window.py --profile mini --tasks OrganizeTable --policies scan
"""

from __future__ import annotations

import logging
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import tyro

from aed_eval.results import write_result
from aed_eval.results.success_window import success_window_record
from aed_eval.results.timing import read_evaluation
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import PAPER_TASK_ORDER

logger = logging.getLogger("success_window")


@dataclass
class Config:
    profile: Profile = "mini"
    """The profile whose evaluations are read; results go to results/<profile>/."""
    runs: Path | None = None
    """Runs folder (default: runs/<profile>, where `aed experiments` writes)."""
    tasks: tuple[str, ...] = PAPER_TASK_ORDER
    policies: tuple[str, ...] = ("naive_dc", "dct", "scan")
    min_outcomes: int = 5
    """Cases with fewer successes or failures than this are skipped (too few to rank)."""
    out: Path | None = None
    """Folder of the records (default: results/<profile>/success_window)."""

    def __post_init__(self) -> None:
        check_profile(self.profile)
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile
        self.out = Path(self.out or Path("results") / self.profile / "success_window")


def main(cfg: Config) -> list[Path]:
    layout = RunLayout(cfg.runs)
    written = []
    for task in cfg.tasks:
        for policy in cfg.policies:
            folder = layout.evaluation(task, policy)
            if not (folder / "scores.json").is_file():
                logger.info("%s / %s: not evaluated (%s), skipped", task, policy, folder)
                continue
            outcomes = [e["success"] for e in read_evaluation(folder)[1]["rollouts"]["episodes"]]
            if min(sum(outcomes), len(outcomes) - sum(outcomes)) < cfg.min_outcomes:
                logger.info(
                    "%s / %s: %d of %d rollouts succeeded: too few of an outcome, skipped",
                    task,
                    policy,
                    sum(outcomes),
                    len(outcomes),
                )
                continue
            record = success_window_record(folder, layout.rollouts(task, policy, "novel"))
            record["command"] = shlex.join(["python", *sys.argv])
            paths = write_result(cfg.out / f"{task}_{policy}.json", record)
            logger.info("%s / %s: %s", task, policy, ", ".join(str(p) for p in paths))
            written += paths
    if not written:
        raise SystemExit(f"{cfg.runs}: no evaluation of {cfg.tasks} x {cfg.policies} to read")
    return written


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

"""Success window: each detector's rollout-level AUROC over whole rollouts beside the same over
the frames up to each success's first success step, and how often a success's maximum score
comes after it (`aed_eval.results.success_window`).

Reads the evaluations and novel rollouts `aed experiments` wrote under `--runs` and writes one
record per case under `results/<profile>/success_window/` (`aed results` re-renders them):

    python scripts/success_window.py --profile mini --tasks OrganizeTable --policies scan
"""

from __future__ import annotations

import logging
from pathlib import Path

import tyro

from aed_eval.figures import CasesConfig as Config
from aed_eval.figures import run_evaluated_cases


def main(cfg: Config) -> list[Path]:
    return run_evaluated_cases("success_window", cfg)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

"""The main experiment (the paper's main-results figure and its statistics table): every task x
{NaiveDC, DCT, SCAN} x {SVDDED, TaskEmbED, LSTMED, DCTED, PrObe}, with the failure-free rnd_oe and
the `time_only` / `random` references. Each (task, policy) case is resumable and committed, once
finished, as a record under `results/<profile>/main/`; `report.md` / `report.png` there cover every
committed case (AUROC and AUPRC with intervals under both endings, Top-1 counts, average rank and
performance difference, success rates, labelled novel episodes).

    python scripts/main_experiment.py --profile mini --tasks PickPlace
    python scripts/main_experiment.py --plan     # what is done and what is left

Every flag of `aed experiments` but `--experiments` applies (`--tasks`, `--policies`, `--runs`,
`--plan`, ...); the run is resumable and skips what is done.
"""

from __future__ import annotations

import sys

from aed_eval.experiments import experiment_script

if __name__ == "__main__":
    sys.exit(experiment_script("main", doc=__doc__))

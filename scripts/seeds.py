"""Stability over five seeds (the paper's error-bar figure): on Pick & Place, every detector of
every policy trained with seeds 0-4 (seed 0 is the main experiment's), their AUROC and AUPRC and
the mean +- std over seeds. Writes one record per policy under `results/<profile>/seeds/`:

    python scripts/seeds.py --profile mini

Every flag of `aed experiments` but `--experiments` applies (`--tasks`, `--policies`, `--runs`,
`--plan`, ...); the run is resumable and skips what is done.
"""

from __future__ import annotations

import sys

from aed_eval.experiments import experiment_script

if __name__ == "__main__":
    sys.exit(experiment_script("seeds", doc=__doc__))

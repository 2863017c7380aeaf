"""Rollout-augmentation ablation (the paper's RA figure): on Pick & Place, every detector of every
policy trained without rollout augmentation beside the main experiment's (with it). Writes one
record per policy under `results/<profile>/rollout_augmentation/`, the main stages first if they
are not done:

    python scripts/rollout_augmentation.py --profile mini

Every flag of `aed experiments` but `--experiments` applies (`--tasks`, `--policies`, `--runs`,
`--plan`, ...); the run is resumable and skips what is done.
"""

from __future__ import annotations

import sys

from aed_eval.experiments import experiment_script

if __name__ == "__main__":
    sys.exit(experiment_script("rollout_augmentation", doc=__doc__))

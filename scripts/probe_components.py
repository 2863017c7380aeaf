"""PrObe's component ablation (the paper's component figure): on Pick & Place with SCAN, the naive
model, then + the pattern extractor, + L_pat, + L_tem (PrObe as the main experiment trains it).
Writes `results/<profile>/probe_components/PickPlace_scan.{json,md}`:

    python scripts/probe_components.py --profile mini

Every flag of `aed experiments` but `--experiments` applies (`--tasks`, `--policies`, `--runs`,
`--plan`, ...); the run is resumable and skips what is done.
"""

from __future__ import annotations

import sys

from aed_eval.experiments import experiment_script

if __name__ == "__main__":
    sys.exit(experiment_script("probe_components", doc=__doc__))

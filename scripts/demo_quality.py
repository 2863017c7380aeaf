"""Demonstration quality (the paper's table): on Press Button, the policies and the detectors given
all-optimal, 2 sub-optimal, or all sub-optimal demonstrations in the novel environments (a
sub-optimal one misses the button once, then presses it). Writes one record per policy under
`results/<profile>/demo_quality/`:

    python scripts/demo_quality.py --profile mini

Every flag of `aed experiments` but `--experiments` applies (`--tasks`, `--policies`, `--runs`,
`--plan`, ...); the run is resumable and skips what is done.
"""

from __future__ import annotations

import sys

from aed_eval.experiments import experiment_script

if __name__ == "__main__":
    sys.exit(experiment_script("demo_quality", doc=__doc__))

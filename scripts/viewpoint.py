"""Viewpoint shift (the paper's table): on Press Button with DCT, the policy and the detectors
trained through the `front` camera and deployed through `front_shift`, beside `front`. Writes
`results/<profile>/viewpoint/PressButton_dct.{json,md}`:

    python scripts/viewpoint.py --profile mini

Every flag of `aed experiments` but `--experiments` applies (`--tasks`, `--policies`, `--runs`,
`--plan`, ...); the run is resumable and skips what is done.
"""

from __future__ import annotations

import sys

from aed_eval.experiments import experiment_script

if __name__ == "__main__":
    sys.exit(experiment_script("viewpoint", doc=__doc__))

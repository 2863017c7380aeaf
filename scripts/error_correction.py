"""The error-correction pilot (the paper's, Press Button with DCT): the policy's novel rollouts
replayed with each detector beside it, corrected to a safe pose at the first alarm (threshold
0.9); success rates without and with each detector, paired on the same environments and seeds
(`aed_eval.correction`). Writes a results record under `results/<profile>/error_correction/`:

    python scripts/error_correction.py --profile mini --task PressButton --policy dct
"""

from __future__ import annotations

import logging
import shlex
import sys
from pathlib import Path

import tyro

from aed_eval.correction import CorrectionConfig
from aed_eval.figures import FigureJob, run_figure


def main(cfg: CorrectionConfig) -> Path:
    written = run_figure(FigureJob("error_correction", cfg, shlex.join(["python", *sys.argv])))
    print(written[1].read_text())
    return written[0]


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(CorrectionConfig))

"""Embedding visualisation (the paper's t-SNE figure): each detector's per-frame embeddings of
20 labelled novel episodes, mapped by t-SNE, normal vs error, coloured by progress
(`aed_eval.embeddings`). Writes a results record, its table and figure under
`results/<profile>/embeddings/`:

    python scripts/embeddings.py --profile mini --task PickPlace --policy scan
"""

from __future__ import annotations

import logging
import shlex
import sys
from pathlib import Path

import tyro

from aed_eval.embeddings import EmbeddingsConfig
from aed_eval.figures import FigureJob, run_figure


def main(cfg: EmbeddingsConfig) -> Path:
    written = run_figure(FigureJob("embeddings", cfg, shlex.join(["python", *sys.argv])))
    print(written[1].read_text())
    return written[0]


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(EmbeddingsConfig))

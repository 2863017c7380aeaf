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

from aed_eval.embeddings import EmbeddingsConfig, embeddings_record
from aed_eval.results import write_result


def main(cfg: EmbeddingsConfig) -> Path:
    record = {**embeddings_record(cfg), "command": shlex.join(["python", *sys.argv])}
    written = write_result(cfg.out / f"{record['task']}_{record['policy']}.json", record)
    print(written[1].read_text())
    return written[0]


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(EmbeddingsConfig))

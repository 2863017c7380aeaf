"""Benchmark float32 against bfloat16 autocast for training the visual detectors on a real
collection: one epoch each, the same draws, its time and mean losses under each precision.

The mini recipe trains a detector under `bf16` only where the epoch is faster and its losses
follow float32's (`aed_models.recipe.DetectorRecipe.precision`); this script is the evidence.
Each (detector, precision) trains from the same seed into its own folder under `--out`, each
detector under both precisions in turn; run it on an otherwise idle machine:

    python scripts/bench_precision.py --runs runs/mini --task OrganizeTable
"""

from __future__ import annotations

import json
import logging
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import tyro

from aed_eval.logs import setup_logging
from aed_models.checkpoint import load_checkpoint
from aed_models.detectors import FAMILY
from aed_models.layout import RunLayout
from aed_models.recipe import PRECISIONS
from aed_models.train.detector import TrainDetectorConfig, train_detector

logger = logging.getLogger("bench_precision")


@dataclass
class Config:
    runs: Path = Path("runs/mini")
    """Runs folder holding `<task>/data/base` (what `aed experiments` collected)."""
    task: str = "OrganizeTable"
    detectors: tuple[str, ...] = ("svdd_ed", "taskemb_ed", "lstm_ed", "dct_ed")
    num_envs: int = 23
    """Training environments (the mini protocol's)."""
    threads: int = 2
    out: Path = Path("runs/bench/precision")
    results: Path = Path("results/bench_precision_mini.json")


@dataclass
class Row:
    detector: str
    precision: str
    epoch_seconds: float
    frames_per_s: float
    losses: dict[str, float]


def one_epoch(cfg: Config, detector: str, precision: str) -> Row:
    run = TrainDetectorConfig.from_preset(
        task=cfg.task,
        detector=detector,
        profile="mini",
        runs=cfg.runs,
        out=cfg.out / f"{detector}_{precision}",
        num_envs=cfg.num_envs,
        epochs=1,
        precision=precision,
        resume=False,
        progress=False,
    )
    started = time.perf_counter()
    path = train_detector(run)
    logger.info("%s %s: %.0f s in all", detector, precision, time.perf_counter() - started)
    entry = load_checkpoint(path, family=FAMILY).extra["log"][-1]
    losses = {k: v for k, v in entry.items() if k not in ("epoch", "seconds", "frames_per_s")}
    return Row(detector, precision, entry["seconds"], entry["frames_per_s"], losses)


def main(cfg: Config) -> None:
    torch.set_num_threads(cfg.threads)
    if not RunLayout(cfg.runs).data(cfg.task, "base").is_dir():
        raise SystemExit(f"{cfg.runs}: no {cfg.task} base collection (run aed experiments)")
    rows = [one_epoch(cfg, d, p) for d in cfg.detectors for p in PRECISIONS]
    for d in cfg.detectors:
        fp32, bf16 = (
            next(r for r in rows if r.detector == d and r.precision == p) for p in PRECISIONS
        )
        logger.info(
            "%s: epoch %.0f s (fp32) -> %.0f s (bf16), %.2fx; loss %.4f -> %.4f",
            d,
            fp32.epoch_seconds,
            bf16.epoch_seconds,
            fp32.epoch_seconds / bf16.epoch_seconds,
            fp32.losses["loss"],
            bf16.losses["loss"],
        )
    cfg.results.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "command": "python scripts/bench_precision.py "
        + f"--runs {cfg.runs} --task {cfg.task} --threads {cfg.threads}",
        "machine": {"cpu": platform.processor() or platform.machine(), "threads": cfg.threads},
        "torch": torch.__version__,
        "rows": [asdict(r) for r in rows],
    }
    cfg.results.write_text(json.dumps(record, indent=1) + "\n")
    logger.info("wrote %s", cfg.results)


if __name__ == "__main__":
    setup_logging()
    main(tyro.cli(Config))

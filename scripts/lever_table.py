"""One policy's variants on the same novel rollout seeds: a lever, or a training-data curve.

Each variant is a checkpoint and the folder `aed rollout` wrote with it (same environments and
rollout seed as the baseline's). A row gives what the variant trained on (environments, agent
successes per environment, epochs, seconds), its action loss, its novel success rate with its
interval, and, paired with the baseline on (environment, rollout seed), how many rollouts only
one of the two succeeded in. Writes a results record (`aed_eval.results`, one entry per
variant) and its Markdown table:

    R=runs/r20/PressButton
    python scripts/lever_table.py --title "SCAN, agent successes per environment" \
        --baseline "10=$R/policies/scan/policy.pt:$R/rollouts/scan/novel" \
        --variants "2=$R/policies_curve/succ2/policy.pt:$R/rollouts_curve/succ2" \
        --out results/mini/levers/PressButton_scan_successes.json
"""

from __future__ import annotations

import logging
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro

from aed_eval.metrics import rate_interval
from aed_eval.results import write_result
from aed_models.train.policy import training_summary
from aed_tasks import trajectory

logger = logging.getLogger("lever_table")


@dataclass
class Config:
    baseline: str
    """`label=checkpoint:rollouts` of the variant the others are paired with."""
    variants: tuple[str, ...] = ()
    """`label=checkpoint:rollouts` of each other variant."""
    title: str = ""
    """The table's heading."""
    out: Path = Path("results/mini/levers/lever.json")
    """The results record (JSON); its Markdown table goes beside it (.md)."""


def parse(spec: str) -> tuple[str, Path, Path]:
    label, sep, paths = spec.partition("=")
    checkpoint, sep2, rollouts = paths.rpartition(":")
    if not (sep and sep2 and label and checkpoint and rollouts):
        raise SystemExit(f"{spec!r}: expected label=checkpoint:rollouts")
    return label, Path(checkpoint), Path(rollouts)


def outcomes(rollouts: Path) -> dict[tuple[int, int], bool]:
    """Success of every rollout, keyed by (environment, rollout seed), in the folder's order."""
    return {
        (r.env_index, r.seed): r.success for r in trajectory.scan_collection(rollouts).episodes()
    }


def training(checkpoint: Path) -> dict:
    """What a checkpoint trained on and how its action loss moved (first and last 5 epochs)."""
    if not checkpoint.is_file():
        raise SystemExit(f"{checkpoint}: no such checkpoint")
    return training_summary(checkpoint)


def record(label: str, checkpoint: Path, rollouts: Path, base: dict) -> dict:
    mine = outcomes(rollouts)
    if set(mine) != set(base):
        raise SystemExit(
            f"{rollouts}: {len(mine)} rollouts on other (environment, seed) pairs than the "
            f"baseline's {len(base)}; roll out with the same --num-envs, --num-episodes, --seed"
        )
    values = np.asarray(list(mine.values()), dtype=float)  # the order policy_table.py reads
    low, high = rate_interval(values)
    return {
        "label": label,
        "checkpoint": str(checkpoint),
        "rollouts_folder": str(rollouts),
        **training(checkpoint),
        "rollouts": len(values),
        "successes": int(values.sum()),
        "success_rate": float(values.mean()),
        "interval": [float(low), float(high)],
        "only_baseline": sum(base[k] and not mine[k] for k in mine),
        "only_this": sum(mine[k] and not base[k] for k in mine),
    }


def main(cfg: Config) -> list[dict]:
    specs = [parse(cfg.baseline), *(parse(v) for v in cfg.variants)]
    base = outcomes(specs[0][2])
    rows = [record(label, ckpt, folder, base) for label, ckpt, folder in specs]
    result = {
        "kind": "lever_table",
        "command": shlex.join(["python", *sys.argv]),
        "title": cfg.title,
        "rows": rows,
    }
    written = write_result(cfg.out, result)
    print(written[1].read_text())
    return rows


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

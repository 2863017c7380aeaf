"""The policies' table: training data and time, action loss, novel success rate beside the paper's.

One row per (task, policy): the rollout folder of `aed rollout` and the checkpoint it names.
Writes a results record (`aed_eval.results`, one entry per row) and its Markdown table; rows of
tasks not measured in this call are kept from the record already at `--out`, so the tasks can be
measured in different runs folders (and sessions):

    python scripts/policy_table.py --runs runs/r20 --tasks PressButton \
        --out results/mini/policies.json
"""

from __future__ import annotations

import json
import logging
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro

from aed_eval.metrics import rate_interval
from aed_eval.paper import POLICY_SUCCESS
from aed_eval.results import write_result
from aed_models.checkpoint import load_checkpoint
from aed_models.layout import RunLayout
from aed_models.train.policy import training_summary
from aed_tasks import PAPER_TASK_ORDER, trajectory

logger = logging.getLogger("policy_table")


@dataclass
class Config:
    runs: Path = Path("runs")
    """Runs folder (the layout of aed_models.layout)."""
    tasks: tuple[str, ...] = ("PressButton",)
    policies: tuple[str, ...] = ("naive_dc", "dct", "scan")
    out: Path = Path("results/mini/policies.json")
    """The results record (JSON); its Markdown table goes beside it (.md)."""


def shared_seconds(layout: RunLayout, task: str) -> dict:
    """The epochs' seconds of the models every policy of the task reads (trained once)."""
    seconds = {}
    for family, path in (("encoder", layout.encoder(task)), ("localizer", layout.localizer(task))):
        if path.is_file():
            log = load_checkpoint(path, family=family).extra["log"]
            seconds[f"{family}_seconds"] = round(sum(e["seconds"] for e in log), 1)
    return seconds


def row(layout: RunLayout, task: str, policy: str) -> dict | None:
    rollouts = layout.rollouts(task, policy, "novel")
    checkpoint = layout.policy(task, policy)
    if not (rollouts.is_dir() and checkpoint.is_file()):
        logger.info("%s / %s: no rollouts or no checkpoint, skipped", task, policy)
        return None
    outcomes = np.asarray(
        [r.success for r in trajectory.scan_collection(rollouts).episodes()], dtype=float
    )
    low, high = rate_interval(outcomes)
    counts = {}
    for ref in trajectory.scan_collection(layout.data(task, "base")).episodes():
        counts[ref.role] = counts.get(ref.role, 0) + 1
    paper = POLICY_SUCCESS.get(task, {}).get(policy)
    return {
        "task": task,
        "policy": policy,
        **training_summary(checkpoint),
        **shared_seconds(layout, task),
        "collection": counts,
        "rollouts": len(outcomes),
        "successes": int(outcomes.sum()),
        "success_rate": float(outcomes.mean()),
        "interval": [float(low), float(high)],
        "paper_success": paper,
    }


def kept_rows(out: Path, tasks: tuple[str, ...]) -> list[dict]:
    """The rows of the record already at `out` for tasks other than `tasks`."""
    if not out.is_file():
        return []
    previous = json.loads(out.read_text())
    if previous.get("kind") != "policy_table":
        raise ValueError(f"{out} is a {previous.get('kind')!r} record, not a policy table")
    command = previous.get("command")  # records written before rows named their command
    return [
        {**r, "command": r.get("command", command)}
        for r in previous["records"]
        if r["task"] not in tasks
    ]


def main(cfg: Config) -> list[dict]:
    layout = RunLayout(cfg.runs)
    command = shlex.join(["python", *sys.argv])
    rows = [
        {**r, "command": command}
        for t in cfg.tasks
        for p in cfg.policies
        if (r := row(layout, t, p)) is not None
    ]
    order = {name: i for i, name in enumerate(PAPER_TASK_ORDER)}
    rows = sorted(kept_rows(cfg.out, cfg.tasks) + rows, key=lambda r: order.get(r["task"], 99))
    record = {"kind": "policy_table", "records": rows}
    written = write_result(cfg.out, record)
    print(written[1].read_text())
    return rows


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

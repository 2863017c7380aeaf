"""Frame-level AUROC of trained detectors on held-out base environments (issue #10's check).

Detectors and policies are trained on the first base environments of a collection; the environments
after them were never seen in training (the script refuses an environment any compared model, the
policy included, trained on, unless --allow-trained-envs). Every agent success and labelled agent
failure of those environments is scored offline by every detector (with each policy's features for
the policy-dependent ones), and the frame-level AUROC (failure frames after the onset against every
other frame) is reported per detector and policy, beside the `time_only` reference (score = frame
index). Failure frames come late in an episode, so the time-matched AUROC (only pairs of frames from
the same 5-step bin; `time_only` ~0.5 there) is reported beside it. Writes JSON, the per-frame
scores (.npz beside it), and prints a Markdown table.

    python scripts/heldout_auroc.py --runs runs/exp --task PressButton --envs 8 9
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro

from aed_eval import metrics
from aed_eval.calibrate import load_policy_checked
from aed_eval.checks import check_held_out
from aed_eval.logs import setup_logging
from aed_eval.scoring import DETECTOR_NAMES, Demonstrations, EpisodeScorer, load_checked_detector
from aed_models.layout import RunLayout
from aed_tasks import trajectory

logger = logging.getLogger("heldout_auroc")


@dataclass
class Config:
    task: str = "PressButton"
    runs: Path = Path("runs")
    """Root of the runs layout holding the trained policies and detectors."""
    data: Path | None = None
    """Base collection (default: <runs>/<task>/data/base)."""
    envs: tuple[int, ...] = (8, 9)
    """Held-out base environments (not used in training)."""
    policies: tuple[str, ...] = ("naive_dc", "dct", "scan")
    detectors: tuple[str, ...] = DETECTOR_NAMES
    num_demos: int = 5
    bin_width: int = 5
    """Time bin (steps) of the time-matched AUROC."""
    out: Path | None = None
    """JSON output (default: <runs>/<task>/heldout_auroc.json)."""
    allow_trained_envs: bool = False
    """Score models on environments they trained on (a diagnostic, marked in the output)."""


def main(cfg: Config) -> dict:
    layout = RunLayout(cfg.runs)
    data = Path(cfg.data or layout.data(cfg.task, "base"))
    refs = [
        e
        for e in trajectory.scan_collection(data).episodes()
        if e.env_index in cfg.envs and e.role in ("agent_success", "agent_failure")
    ]
    if not refs:
        raise SystemExit(f"{data}: no agent episodes in environments {cfg.envs}")
    labels = [ref.frame_labels() for ref in refs]
    demos = Demonstrations(data, "base", cfg.num_demos)
    results: dict = {
        "task": cfg.task,
        "data": str(data),
        "envs": list(cfg.envs),
        "episodes": len(refs),
        "failures": sum(r.error_onset is not None for r in refs),
        "auroc": {},
        "time_matched": {},
    }
    time_only = [np.arange(r.num_frames, dtype=float) for r in refs]
    results["auroc"]["time_only"] = metrics.frame_auroc(time_only, labels)
    results["time_matched"]["time_only"] = metrics.time_matched_auroc(
        time_only, labels, cfg.bin_width
    )
    arrays = {"lengths": np.array([r.num_frames for r in refs]), "labels": np.concatenate(labels)}
    for policy_name in cfg.policies:
        start = time.perf_counter()
        policy, sha = load_policy_checked(layout.policy(cfg.task, policy_name))
        detectors = [
            load_checked_detector(layout.detector(cfg.task, d, policy_name), d, cfg.task, sha)
            for d in cfg.detectors
        ]
        models = {
            f"policy {policy_name}": policy.checkpoint_extra,
            **{f"detector {d.name}": d.model.checkpoint_extra for d in detectors},
        }
        overlap = check_held_out(models, "base", cfg.envs, "heldout_auroc", cfg.allow_trained_envs)
        results.setdefault("trained_env_overlap", {}).update(overlap)
        scorer = EpisodeScorer(detectors, policy, demos)
        scores: dict[str, list[np.ndarray]] = {d.name: [] for d in detectors}
        for ref in refs:
            for name, s in scorer.score(ref).items():
                scores[name].append(s)
        scorer.close()
        results["auroc"][policy_name] = {
            name: metrics.frame_auroc(s, labels) for name, s in scores.items()
        }
        results["time_matched"][policy_name] = {
            name: metrics.time_matched_auroc(s, labels, cfg.bin_width) for name, s in scores.items()
        }
        arrays.update({f"{policy_name}/{name}": np.concatenate(s) for name, s in scores.items()})
        logger.info(
            "%s: %s (%.0f s)",
            policy_name,
            results["auroc"][policy_name],
            time.perf_counter() - start,
        )
    out = Path(cfg.out or Path(cfg.runs) / cfg.task / "heldout_auroc.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    np.savez_compressed(out.with_suffix(".npz"), **arrays)
    print(format_table(results, cfg))
    return results


def format_table(results: dict, cfg: Config) -> str:
    auroc, matched = results["auroc"], results["time_matched"]
    flag = (
        "DIAGNOSTIC (environments a model trained on): "
        if results.get("trained_env_overlap")
        else ""
    )
    lines = [
        f"{flag}Frame-level AUROC / time-matched AUROC, {results['task']} held-out base "
        f"environments {results['envs']} ({results['episodes']} episodes, {results['failures']} "
        f"failures); time_only = {auroc['time_only']:.3f} / {matched['time_only']:.3f}",
        "",
        "| policy | " + " | ".join(cfg.detectors) + " |",
        "|---|" + "---:|" * len(cfg.detectors),
    ]
    for policy in cfg.policies:
        cells = [f"{auroc[policy][d]:.3f} / {matched[policy][d]:.3f}" for d in cfg.detectors]
        lines.append(f"| {policy} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    setup_logging()
    try:
        main(tyro.cli(Config))
    except ValueError as e:
        logger.error("%s", e)
        raise SystemExit(2) from None

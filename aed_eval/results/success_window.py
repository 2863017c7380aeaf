"""Success-window AUROC: does what a successful rollout does after its success decide the
rollout-level AUROC?

Every rollout runs the horizon (the protocol's default ending), while the detectors trained on
base episodes that end at success: a success's later frames are new to them. This record sets,
per detector, the exact pairwise AUROC over whole rollouts beside the same AUROC with each
(success, failure) pair compared over the frames up to that success's first success step, and
the share of successes whose maximum comes after it. Built from one evaluation folder
(`scores.json`) and the rollouts' stored success steps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from aed_eval import metrics
from aed_eval.evaluate import MIN_PER_OUTCOME, too_small
from aed_eval.results import command_line, renderer
from aed_eval.results.timing import read_evaluation
from aed_eval.rollout import stored_rollouts


def success_steps(rollouts: Path, policy: str, policy_sha256: str) -> dict[tuple[int, int], int]:
    """(environment, episode seed) -> first success step of each successful rollout."""
    stored = stored_rollouts(Path(rollouts), policy, policy_sha256)
    return {
        (int(e["env_index"]), int(e["episode_seed"])): int(e["success_step"])
        for e in stored.entries
        if e["success"] and e.get("success_step") is not None
    }


def success_window_record(
    evaluation: Path, rollouts: Path, bootstrap: int = metrics.NUM_BOOTSTRAP, seed: int = 0
) -> dict[str, Any]:
    """The record of one (task, policy) evaluation under the horizon ending."""
    results, scored = read_evaluation(evaluation)
    if results["ending"] != "horizon":
        raise ValueError(f"{evaluation}: rollouts end at {results['ending']}, not the horizon")
    episodes = scored["rollouts"]["episodes"]
    success_rows = [i for i, e in enumerate(episodes) if e["success"]]
    failure_rows = [i for i, e in enumerate(episodes) if not e["success"]]
    record = {
        "kind": "success_window",
        "task": results["task"],
        "policy": results["policy"],
        "policy_sha256": results["policy_sha256"],
        "evaluation": str(evaluation),
        "successes": len(success_rows),
        "failures": len(failure_rows),
    }
    if too_small(record):
        return {**record, "success_steps": [], "detectors": {}}
    steps = success_steps(rollouts, results["policy"], results["policy_sha256"])
    missing = [
        episodes[i]
        for i in success_rows
        if (episodes[i]["env_index"], episodes[i]["seed"]) not in steps
    ]
    if missing:
        raise ValueError(f"{rollouts}: no success step for {len(missing)} scored successes")
    k = [steps[episodes[i]["env_index"], episodes[i]["seed"]] for i in success_rows]
    detectors = {}
    for name, curves in scored["rollouts"]["scores"].items():
        successes = [np.asarray(curves[i], dtype=float) for i in success_rows]
        failures = [np.asarray(curves[i], dtype=float) for i in failure_rows]
        whole = metrics.success_window_pairs(successes, [len(s) - 1 for s in successes], failures)
        window = metrics.success_window_pairs(successes, k, failures)
        after = [
            float(np.max(s[j + 1 :], initial=-np.inf)) > float(np.max(s[: j + 1]))
            for s, j in zip(successes, k, strict=True)
        ]
        detectors[name] = {
            "whole_auroc": float(whole.mean()),
            "whole_interval": metrics.pairs_interval(whole, bootstrap, seed),
            "window_auroc": float(window.mean()),
            "window_interval": metrics.pairs_interval(window, bootstrap, seed),
            "max_after_success": float(np.mean(after)),
        }
    return {**record, "success_steps": sorted(k), "detectors": detectors}


def _auroc(value: float, interval: list[float]) -> str:
    return f"{value:.3f} [{interval[0]:.2f}, {interval[1]:.2f}]"


@renderer("success_window")
def render_success_window(record: dict[str, Any], stem: Path) -> list[Path]:
    """A Markdown table: per detector the two AUROCs and the share of late maxima."""
    md = stem.with_suffix(".md")
    if not record["detectors"]:
        md.write_text(
            f"Success window, {record['task']} / {record['policy']}: {record['successes']} "
            f"successes against {record['failures']} failures, fewer than {MIN_PER_OUTCOME} of an "
            "outcome: too few to rank.\n" + command_line(record)
        )
        return [md]
    steps = record["success_steps"]
    lines = [
        f"Success window, {record['task']} / {record['policy']}: {record['successes']} successes "
        f"against {record['failures']} failures, every rollout to the horizon. Exact pairwise "
        "AUROC (95% bootstrap, each outcome resampled within itself) over whole rollouts, and "
        "over each pair's frames up to the success's first success step (median step "
        f"{np.median(steps):g}, range {min(steps)}-{max(steps)}); the share of successes whose "
        "maximum score comes after their success.\n",
        "| detector | AUROC, whole rollouts | AUROC, up to the success | maximum after success |",
        "|---|---:|---:|---:|",
    ]
    for name, d in record["detectors"].items():
        lines.append(
            f"| {name} | {_auroc(d['whole_auroc'], d['whole_interval'])} | "
            f"{_auroc(d['window_auroc'], d['window_interval'])} | {d['max_after_success']:.2f} |"
        )
    md.write_text("\n".join(lines) + "\n" + command_line(record))
    return [md]

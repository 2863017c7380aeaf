"""Timing accuracy (the paper's score-curve figure): every detector's score through a successful
rollout, a failed one and a labelled failure of the novel split, against its calibrated
threshold, with the labelled onset and each detector's first alarm.

Built from one evaluation folder (`aed evaluate`: `results.json` for the thresholds and the
detection delays over every labelled failure, `scores.json` for the curves). The episodes shown
are the first of each kind in (environment, seed) order, not chosen by how well any detector
does on them.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from aed_eval.metrics import first_alarm
from aed_eval.results import command_line, renderer, save_figure

logger = logging.getLogger(__name__)

PANELS = (
    ("successful rollout", "rollouts", lambda e: e["success"]),
    ("failed rollout", "rollouts", lambda e: not e["success"]),
    ("labelled failure", "labelled", lambda e: e.get("onset_frame") is not None),
)


def read_evaluation(folder: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """An evaluation folder's results and per-frame scores, checked to be there."""
    bodies = []
    for name in ("results.json", "scores.json"):
        path = Path(folder) / name
        try:
            bodies.append(json.loads(path.read_text()))
        except FileNotFoundError as e:
            raise FileNotFoundError(f"{path}: missing; run `aed evaluate` first") from e
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: unreadable ({e})") from e
    return bodies[0], bodies[1]


def timing_record(
    folder: Path, calibration: str = "policy", alpha: float = 0.1, digits: int = 4
) -> dict[str, Any]:
    """The record of one (task, policy) evaluation: per panel the chosen episode and every
    detector's curve (`digits` significant digits) and first alarm; per detector the threshold
    and the detection delays over every labelled failure."""
    results, scored = read_evaluation(folder)
    detectors = list(scored["rollouts"]["scores"])
    key = _threshold_key(results, detectors, calibration, alpha)
    thresholds, delays = {}, {}
    for d in detectors:
        calibrated = results["detectors"][d][results["ending"]]["calibrated"]
        if key not in calibrated:
            raise ValueError(f"{folder}: {d} has no {key} threshold; known {sorted(calibrated)}")
        thresholds[d] = calibrated[key]["threshold"]
        delays[d] = results["detectors"][d].get("labelled", {}).get("delays", {}).get(key)
    panels = []
    for title, group, wanted in PANELS:
        episodes = scored.get(group, {}).get("episodes", [])
        order = sorted(
            range(len(episodes)), key=lambda i: (episodes[i]["env_index"], episodes[i]["seed"])
        )
        index = next((i for i in order if wanted(episodes[i])), None)
        if index is None:
            continue
        curves = {d: scored[group]["scores"][d][index] for d in detectors}
        panels.append(
            {
                "title": title,
                "episode": episodes[index],
                "scores": {d: [float(f"{v:.{digits}g}") for v in c] for d, c in curves.items()},
                "first_alarm": {
                    d: first_alarm(np.asarray(c), thresholds[d]) for d, c in curves.items()
                },
            }
        )
    return {
        "kind": "timing_accuracy",
        "task": results["task"],
        "policy": results["policy"],
        "policy_sha256": results["policy_sha256"],
        "evaluation": str(folder),
        "calibration": key,
        "thresholds": thresholds,
        "labelled_delays": delays,
        "panels": panels,
    }


def _threshold_key(
    results: dict[str, Any], detectors: list[str], calibration: str, alpha: float
) -> str:
    """`<calibration>@<alpha>`; `policy` falls back to `expert` when the policy had no success
    among its calibration rollouts, so that no detector has a `policy@` threshold."""
    key, fallback = f"{calibration}@{alpha:g}", f"expert@{alpha:g}"
    known = {k for d in detectors for k in results["detectors"][d][results["ending"]]["calibrated"]}
    if calibration == "policy" and key not in known and fallback in known:
        logger.info(
            "%s / %s: no %s threshold (no policy success to calibrate on): %s instead",
            results["task"],
            results["policy"],
            key,
            fallback,
        )
        return fallback
    return key


def _median(delay: dict[str, Any] | None) -> str:
    """The median delay, `-` when every labelled failure was missed (no delay to take)."""
    if delay is None:
        return ""
    median = delay["median_delay"]
    return f"{median:g}" if median is not None and np.isfinite(median) else "-"


def _alarm(frame: int | None, onset: int | None) -> str:
    if frame is None:
        return "none"
    return f"{frame}" if onset is None else f"{frame} ({frame - onset:+d})"


@renderer("timing_accuracy")
def render_timing(record: dict[str, Any], stem: Path) -> list[Path]:
    """A Markdown table (first alarms on the panels' episodes; delays over every labelled
    failure) and the curves' figure (a row per detector, a column per episode)."""
    detectors = list(record["thresholds"])
    panels = record["panels"]
    heads = [
        f"{p['title']} (env {p['episode']['env_index']}"
        + (f", onset {p['episode']['onset_frame']}" if p["episode"].get("onset_frame") else "")
        + ")"
        for p in panels
    ]
    lines = [
        f"Timing accuracy, {record['task']} / {record['policy']}: first alarm (frame; after the "
        f"onset, its delay) at the {record['calibration']} threshold; over every labelled "
        "failure, early / on time / late / missed and the median delay.\n",
        "| detector | threshold | " + " | ".join(heads) + " | labelled failures | median delay |",
        "|---|---:|" + "---:|" * len(panels) + "---|---:|",
    ]
    for d in detectors:
        alarms = [_alarm(p["first_alarm"][d], p["episode"].get("onset_frame")) for p in panels]
        delay = record["labelled_delays"].get(d)
        counts = "" if delay is None else " / ".join(str(v) for v in delay["counts"].values())
        median = _median(delay)
        lines.append(
            f"| {d} | {record['thresholds'][d]:.4g} | "
            + " | ".join(alarms)
            + f" | {counts} | {median} |"
        )
    md = stem.with_suffix(".md")
    md.write_text("\n".join(lines) + "\n" + command_line(record))
    return [md, _plot(record, detectors, Path(f"{stem}.png"))]


def _plot(record: dict[str, Any], detectors: list[str], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = record["panels"]
    fig, axes = plt.subplots(
        len(detectors),
        max(len(panels), 1),
        figsize=(3.6 * max(len(panels), 1), 1.7 * len(detectors)),
        sharey="row",
        squeeze=False,
    )
    for row, d in enumerate(detectors):
        for col, panel in enumerate(panels):
            ax = axes[row, col]
            ax.plot(panel["scores"][d], color="tab:blue", linewidth=1)
            ax.axhline(record["thresholds"][d], color="grey", linestyle="--", linewidth=0.8)
            onset = panel["episode"].get("onset_frame")
            if onset is not None:
                ax.axvline(onset, color="red", linestyle="--", linewidth=0.8)
            alarm = panel["first_alarm"][d]
            if alarm is not None:
                ax.plot(alarm, panel["scores"][d][alarm], "v", color="black", markersize=5)
            if row == 0:
                ax.set_title(panel["title"], fontsize=9)
            if col == 0:
                ax.set_ylabel(d, fontsize=8)
            ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("frame", fontsize=8)
    fig.suptitle(
        f"{record['task']} / {record['policy']}: scores, {record['calibration']} threshold "
        "(dashed), labelled onset (red), first alarm (triangle)",
        fontsize=9,
    )
    fig.tight_layout()
    return save_figure(fig, path)

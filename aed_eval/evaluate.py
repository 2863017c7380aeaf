"""`aed evaluate`: the paper's main experiment for one task and policy, and more.

A policy's stored novel-split rollouts are scored offline by every trained detector; per
detector: rollout-level AUROC and AUPRC under the default ending and the paper's (cut at the
first success), rates at each calibrated threshold, and on labelled novel episodes frame-level
AUROC and detection delays, each with a 95% bootstrap interval. The `time_only` and `random`
reference rows show how much of a number is length. A model is never scored on an environment
it trained on. Results: `runs/<task>/<policy>/eval/` (`results.json`, `results.md`,
`scores.json`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro

from aed_eval import metrics
from aed_eval.calibrate import SOURCES, load_policy_checked, read_calibration, threshold_at
from aed_eval.checks import check_camera, check_detectors, check_held_out, task_class
from aed_eval.rollout import paper_ending, stored_rollouts
from aed_eval.scoring import (
    DETECTOR_NAMES,
    Demonstrations,
    EpisodeScorer,
    load_checked_detector,
)
from aed_models.layout import RunLayout
from aed_tasks import trajectory
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)

REFERENCES = ("time_only", "random")
ENDING_TITLES = {
    "horizon": "every rollout runs the horizon",
    "success": "stopped at first success (the paper's ending)",
}
MIN_PER_OUTCOME = 5  # fewer rollouts of either outcome: reported, too small to rank


@dataclass
class EvaluateConfig:
    """What `aed evaluate` scores (paths default to the `runs/<task>/...` layout)."""

    task: str = "PressButton"
    """Task name."""
    policy: str = "naive_dc"
    """Policy whose rollouts are evaluated."""
    detectors: tuple[str, ...] = DETECTOR_NAMES
    """Detectors to evaluate (each trained with aed train-detector)."""
    split: Literal["base", "novel"] = "novel"
    """Split of the rollouts."""
    rollouts: Path | None = None
    """Policy rollouts (default: runs/<task>/rollouts/<policy>/<split>)."""
    demos: Path | None = None
    """Demonstrations of the split's environments (default: runs/<task>/data/<split>)."""
    labelled: Path | None = None
    """Labelled expert episodes of the split
    (default: runs/<task>/data/<split>-labelled, if present)."""
    out: Path | None = None
    """Output folder (default: runs/<task>/<policy>/eval)."""
    num_demos: int = 5
    """Demonstrations per environment given to the detectors."""
    num_suboptimal_demos: int = 0
    """Of the `num_demos`, how many are sub-optimal (the demonstration-quality experiment)."""
    suboptimal_demos: Path | None = None
    """Collection holding the sub-optimal demonstrations (default: `demos`)."""
    camera: str = "front"
    """Camera the rollouts, demonstrations and labelled episodes were recorded through
    (front_shift: the viewpoint-shift experiment)."""
    window: int = 10
    """Frames after a labelled onset within which an alarm counts as on time."""
    bootstrap: int = metrics.NUM_BOOTSTRAP
    """Resamples of every bootstrap interval."""
    allow_trained_envs: bool = False
    """Score models on environments they trained on (a diagnostic, marked in the output)."""
    seed: int = 0
    """Seed of the `random` reference and of the bootstrap."""
    runs: Path = Path("runs")
    """Root of the runs folder (see aed_models.layout)."""
    progress: bool = True
    """Show progress bars."""

    def __post_init__(self) -> None:
        from aed_models.policies import POLICIES

        self.task = task_class(self.task).task_name
        POLICIES.check(self.policy)
        check_detectors(self.detectors)
        if not 0 <= self.num_suboptimal_demos <= self.num_demos:
            raise ValueError(
                f"num_suboptimal_demos={self.num_suboptimal_demos}: 0..num_demos={self.num_demos}"
            )
        if self.num_demos < 1 or self.window < 0 or self.bootstrap < 1:
            raise ValueError(
                f"num_demos={self.num_demos}, window={self.window}, bootstrap={self.bootstrap}: "
                "num_demos >= 1, window >= 0, bootstrap >= 1"
            )
        check_camera(self.camera)
        layout = RunLayout(self.runs)
        self.rollouts = Path(self.rollouts or layout.rollouts(self.task, self.policy, self.split))
        self.demos = Path(self.demos or layout.data(self.task, self.split))
        if self.labelled is None and layout.labelled(self.task, self.split).is_dir():
            self.labelled = layout.labelled(self.task, self.split)
        self.out = Path(self.out or layout.evaluation(self.task, self.policy))


def stats(values: list[int]) -> dict[str, float]:
    if not values:
        return {"count": 0}
    v = np.asarray(values)
    return {
        "count": len(v),
        "min": int(v.min()),
        "median": float(np.median(v)),
        "max": int(v.max()),
        "mean": float(v.mean()),
    }


@dataclass
class EndingView:
    """The rollouts as one ending sees them: frames per rollout and outcome."""

    frames: list[int]  # T + 1 per rollout
    failed: np.ndarray

    def cut(self, scores: list[np.ndarray]) -> list[np.ndarray]:
        return [s[:n] for s, n in zip(scores, self.frames, strict=True)]


def ending_views(entries: list[dict[str, Any]], recorded: str) -> dict[str, EndingView]:
    """The recorded ending, and the paper's as a view of horizon rollouts (cut at first success)."""
    full = EndingView(
        [int(e["elapsed_steps"]) + 1 for e in entries],
        np.asarray([not e["success"] for e in entries]),
    )
    if recorded != "horizon":
        return {recorded: full}
    paper = [paper_ending(e) for e in entries]
    return {
        "horizon": full,
        "success": EndingView([n + 1 for n, _ in paper], np.asarray([not ok for _, ok in paper])),
    }


def success_rate(refs: list[trajectory.EpisodeRef], seed: int, num: int) -> dict[str, Any]:
    """Rate over rollouts with its bootstrap interval, and the paper's mean ± std over
    environments."""
    per_env: dict[int, list[bool]] = {}
    for ref in refs:
        per_env.setdefault(ref.env_index, []).append(ref.success)
    rates = np.asarray([np.mean(v) for v in per_env.values()])
    outcomes = np.asarray([r.success for r in refs], dtype=float)
    return {
        "rate": float(outcomes.mean()),
        "interval": metrics.rate_interval(outcomes, num, seed),
        "successes": int(outcomes.sum()),
        "mean": float(rates.mean()),
        "std": float(rates.std()),
        "num_envs": len(rates),
        "per_env": {str(k): float(np.mean(v)) for k, v in sorted(per_env.items())},
    }


def curve_metrics(
    scores: list[np.ndarray], failed: np.ndarray, output: str, cfg: EvaluateConfig
) -> dict[str, Any]:
    """AUROC and AUPRC with intervals, and the ROC curve (thinned) of one detector under one
    ending."""
    maxima = metrics.rollout_maxima(scores)
    grid = metrics.thresholds("distance" if output == "distance" else "probability", maxima)
    curves = metrics.rollout_curves(maxima, failed, grid)
    intervals = metrics.curve_intervals(maxima, failed, grid, cfg.bootstrap, cfg.seed)
    return {
        "auroc": curves.auroc,
        "auroc_interval": intervals["auroc"],
        "auprc": curves.auprc,
        "auprc_interval": intervals["auprc"],
        "roc": {"fpr": curves.fpr.tolist()[::50], "tpr": curves.tpr.tolist()[::50]},
    }


def labelled_metrics(
    scores: list[np.ndarray],
    refs: list[trajectory.EpisodeRef],
    thresholds: dict[str, float],
    cfg: EvaluateConfig,
) -> dict[str, Any]:
    """Frame-level AUROC and time-matched AUROC (intervals over episodes) and, at each
    threshold, detection delays.

    Error frames come late in an episode, so the frame AUROC credits a score that only grows
    with time; the time-matched AUROC compares frames of the same 5-step bin only, where the
    step count alone (`time_only`) scores about 0.5.
    """
    labels = [ref.frame_labels()[: len(s)] for ref, s in zip(refs, scores, strict=True)]
    failures = np.asarray([r.error_onset is not None for r in refs])
    result: dict[str, Any] = {"episodes": len(refs), "delays": {}}
    for key, auroc in (
        ("frame_auroc", metrics.frame_auroc),
        ("time_matched_auroc", metrics.time_matched_auroc),
    ):
        result[key] = auroc(scores, labels)
        result[f"{key}_interval"] = metrics.stratified_bootstrap(
            lambda idx, auroc=auroc: auroc([scores[i] for i in idx], [labels[i] for i in idx]),
            [np.flatnonzero(failures), np.flatnonzero(~failures)],
            cfg.bootstrap,
            seed=cfg.seed,
        )
    onsets = [
        (s, r.onset_frame) for s, r in zip(scores, refs, strict=True) if r.onset_frame is not None
    ]
    if onsets:
        for key, threshold in thresholds.items():
            result["delays"][key] = metrics.detection_delays(
                [s for s, _ in onsets], [o for _, o in onsets], threshold, cfg.window
            )
    return result


def score_all(
    scorer: EpisodeScorer,
    refs: list[trajectory.EpisodeRef],
    names: list[str],
    desc: str,
    progress: bool,
) -> dict[str, list[np.ndarray]]:
    from tqdm.auto import tqdm

    scores: dict[str, list[np.ndarray]] = {name: [] for name in names}
    for ref in tqdm(refs, desc=desc, disable=not progress):
        for name, s in scorer.score(ref).items():
            scores[name].append(s)
    return scores


@locks_out_folder  # one evaluation per out folder (aed_tasks.locks)
def evaluate_policy(cfg: EvaluateConfig) -> dict[str, Any]:
    """Score every rollout by every detector and compute the metrics (see the module doc)."""
    layout = RunLayout(cfg.runs)
    policy, policy_sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    stored = stored_rollouts(Path(cfg.rollouts), cfg.policy, policy_sha)
    refs = stored.refs
    detectors = [
        load_checked_detector(layout.detector(cfg.task, d, cfg.policy), d, cfg.task, policy_sha)
        for d in cfg.detectors
    ]
    models = {
        f"policy {cfg.policy}": policy.checkpoint_extra,
        **{f"detector {d.name}": d.model.checkpoint_extra for d in detectors},
    }
    overlaps = check_held_out(
        models, cfg.split, {r.env_index for r in refs}, "evaluate", cfg.allow_trained_envs
    )
    labelled_refs: list[trajectory.EpisodeRef] = []
    if cfg.labelled is not None:
        labelled_refs = [
            e
            for e in trajectory.scan_collection(Path(cfg.labelled)).episodes()
            if e.role in ("agent_success", "agent_failure")
        ]
        for split in {e.split for e in labelled_refs}:
            overlaps.update(
                check_held_out(
                    models,
                    split,
                    {e.env_index for e in labelled_refs if e.split == split},
                    "evaluate (labelled episodes)",
                    cfg.allow_trained_envs,
                )
            )

    roots = [Path(cfg.demos)] + ([Path(cfg.labelled)] if cfg.labelled is not None else [])
    roots += [Path(cfg.suboptimal_demos)] if cfg.suboptimal_demos is not None else []
    demos = Demonstrations(roots, cfg.split, cfg.num_demos, cfg.num_suboptimal_demos, cfg.camera)
    scorer = EpisodeScorer(detectors, policy, demos)
    names = [d.name for d in detectors]
    per_detector = score_all(scorer, refs, names, f"score {cfg.policy} rollouts", cfg.progress)
    labelled_scores = score_all(
        scorer, labelled_refs, names, "score labelled episodes", cfg.progress
    )
    scorer.close()

    views = ending_views(stored.entries, stored.ending)
    full_frames = views[stored.ending].frames
    references = {
        "time_only": metrics.time_only_scores(full_frames, stored.horizon),
        "random": metrics.random_scores(full_frames, cfg.seed),
    }
    results: dict[str, Any] = {
        "task": cfg.task,
        "policy": cfg.policy,
        "policy_sha256": policy_sha,
        "split": cfg.split,
        "demos": {"count": cfg.num_demos, "suboptimal": cfg.num_suboptimal_demos},
        "camera": cfg.camera,
        "ending": stored.ending,
        "endings": list(views),
        "diagnostic": bool(overlaps),
        "trained_env_overlap": overlaps,
        "rollouts": {
            "count": len(refs),
            "failures": int(views[stored.ending].failed.sum()),
            "success_rate": success_rate(refs, cfg.seed, cfg.bootstrap),
            "horizon": stored.horizon,
            "lengths": {
                ending: {
                    "success": stats(
                        [n - 1 for n, f in zip(v.frames, v.failed, strict=True) if not f]
                    ),
                    "failure": stats([n - 1 for n, f in zip(v.frames, v.failed, strict=True) if f]),
                }
                for ending, v in views.items()
            },
            "outcomes": {
                ending: {"failures": int(v.failed.sum()), "successes": int((~v.failed).sum())}
                for ending, v in views.items()
            },
        },
        "detectors": {},
        "references": {},
    }
    for d in detectors:
        calibrations = {
            source: read_calibration(d.path, d.model.checkpoint_sha256, source)
            for source in SOURCES
        }
        thresholds = {
            f"{source}@{alpha}": t
            for source, body in calibrations.items()
            if body
            for alpha in body["thresholds"]
            if (t := threshold_at(body, float(alpha))) is not None
        }
        row: dict[str, Any] = {
            "output": d.output,
            "calibration": {s: _calibration_summary(b) for s, b in calibrations.items() if b},
        }
        for ending, view in views.items():
            cut = view.cut(per_detector[d.name])
            row[ending] = curve_metrics(cut, view.failed, d.output, cfg)
            row[ending]["calibrated"] = {
                key: metrics.alarm_rates(cut, view.failed, t).to_dict()
                for key, t in thresholds.items()
            }
        if labelled_refs:
            row["labelled"] = labelled_metrics(
                labelled_scores[d.name], labelled_refs, thresholds, cfg
            )
        results["detectors"][d.name] = row
    for name, scores in references.items():
        results["references"][name] = {
            ending: curve_metrics(view.cut(scores), view.failed, "probability", cfg)
            for ending, view in views.items()
        }
    if labelled_refs:
        lengths = [len(x) for x in labelled_scores[names[0]]]
        results["labelled_references"] = {
            name: labelled_metrics(scores, labelled_refs, {}, cfg)
            for name, scores in (
                ("time_only", metrics.time_only_scores(lengths, stored.horizon)),
                ("random", metrics.random_scores(lengths, cfg.seed)),
            )
        }
    write_results(
        Path(cfg.out),
        results,
        {"rollouts": (refs, per_detector), "labelled": (labelled_refs, labelled_scores)},
    )
    return results


def _calibration_summary(body: dict[str, Any]) -> dict[str, Any]:
    return {
        k: body.get(k) for k in ("thresholds", "num_rollouts", "of_rollouts", "envs", "diagnostic")
    }


def write_results(
    out: Path, results: dict[str, Any], scored: dict[str, tuple[list, dict[str, list[np.ndarray]]]]
) -> None:
    """results.json, results.md, and scores.json (per-frame scores of every scored episode)."""
    out.mkdir(parents=True, exist_ok=True)
    trajectory.write_json_atomic(out / "results.json", results)
    trajectory.write_json_atomic(
        out / "scores.json",
        {
            group: {
                "episodes": [
                    {
                        "env_index": r.env_index,
                        "seed": r.seed,
                        "success": r.success,
                        "role": r.role,
                        "onset_frame": r.onset_frame,
                    }
                    for r in refs
                ],
                "scores": {
                    name: [np.round(s, 6).tolist() for s in values]
                    for name, values in scores.items()
                },
            }
            for group, (refs, scores) in scored.items()
        },
    )
    (out / "results.md").write_text(format_results(results) + "\n")


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}f}"


def delay_counts_text(delays: dict[str, Any]) -> str:
    """`key: early/on time/late/missed` counts of each threshold's detection delays ('-': none)."""
    return (
        "; ".join(
            f"{k}: " + "/".join(str(v["counts"][c]) for c in metrics.DELAY_CLASSES)
            for k, v in delays.items()
        )
        or "-"
    )


def with_interval(value: Any, interval: Any, digits: int = 3) -> str:
    """`0.712 [0.60, 0.81]`, or `-` when undefined."""
    if value is None or not np.isfinite(value):
        return "-"
    low, high = interval if interval is not None else (float("nan"), float("nan"))
    return f"{value:.{digits}f} [{_f(low, min(digits, 2))}, {_f(high, min(digits, 2))}]"


def labelled_cells(lab: dict[str, Any]) -> str:
    """`frame AUROC | time-matched AUROC | delays` of one detector's (or reference's) labelled
    metrics."""
    return " | ".join(
        [
            with_interval(lab.get("frame_auroc"), lab.get("frame_auroc_interval")),
            with_interval(lab.get("time_matched_auroc"), lab.get("time_matched_auroc_interval")),
            delay_counts_text(lab.get("delays", {})),
        ]
    )


def too_small(outcomes: dict[str, int]) -> bool:
    return min(outcomes["failures"], outcomes["successes"]) < MIN_PER_OUTCOME


def format_results(results: dict[str, Any]) -> str:
    r = results["rollouts"]
    sr = r["success_rate"]
    lines = [f"## {results['task']} / {results['policy']} ({results['split']} split)", ""]
    if results["diagnostic"]:
        lines += [
            (
                "**DIAGNOSTIC: scored on environments a model trained on** "
                f"{results['trained_env_overlap']}."
            ),
            "",
        ]
    lines += [
        "Policy success rate "
        f"{with_interval(100 * sr['rate'], [100 * x for x in sr['interval']], 1)}% "
        f"({sr['successes']}/{r['count']} rollouts; per environment {100 * sr['mean']:.1f} ± "
        f"{100 * sr['std']:.1f}% over {sr['num_envs']}). Horizon {r['horizon']} steps.",
        "",
        "| detector | " + " | ".join(f"AUROC, {e} | AUPRC, {e}" for e in results["endings"]) + " |",
        "|---|" + "---:|---:|" * len(results["endings"]),
    ]
    rows = [
        *results["detectors"].items(),
        *((f"*{k}*", v) for k, v in results["references"].items()),
    ]
    for name, row in rows:
        cells = [
            c
            for e in results["endings"]
            for c in (
                with_interval(row[e]["auroc"], row[e]["auroc_interval"]),
                with_interval(row[e]["auprc"], row[e]["auprc_interval"]),
            )
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    for ending in results["endings"]:
        o, lengths = r["outcomes"][ending], r["lengths"][ending]
        flag = (
            f" Too small to rank (fewer than {MIN_PER_OUTCOME} of an outcome)."
            if too_small(o)
            else ""
        )
        lines.append(
            f"- *{ending}*: {ENDING_TITLES[ending]}; {o['successes']} successes (median "
            f"{lengths['success'].get('median', '-')} steps), {o['failures']} failures (median "
            f"{lengths['failure'].get('median', '-')} steps).{flag}"
        )
    lines += [
        "",
        f"At the calibrated thresholds ({results['ending']} ending): realised false-alarm rate on "
        "the novel successes [Wilson 95%], TPR, TNR",
        "",
        "| detector | calibration | FAR | TPR | TNR | bal. acc. |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for name, row in results["detectors"].items():
        for key, rates in row[results["ending"]]["calibrated"].items():
            lines.append(
                f"| {name} | {key} | "
                f"{with_interval(rates['false_alarm_rate'], rates['false_alarm_interval'], 2)} | "
                f"{_f(rates['tpr'], 2)} | {_f(rates['tnr'], 2)} | "
                f"{_f(rates['balanced_accuracy'], 2)} |"
            )
    if any("labelled" in row for row in results["detectors"].values()):
        lines += [
            "",
            "Labelled novel episodes (expert successes and injected failures)",
            "",
            "| detector | frame AUROC | time-matched AUROC | delays early/on time/late/missed |",
            "|---|---:|---:|---|",
        ]
        rows = [
            *((name, row.get("labelled", {})) for name, row in results["detectors"].items()),
            *((f"*{k}*", v) for k, v in results.get("labelled_references", {}).items()),
        ]
        for name, lab in rows:
            lines.append(f"| {name} | {labelled_cells(lab)} |")
    return "\n".join(lines)


def evaluate(cfg: Annotated[EvaluateConfig, tyro.conf.arg(name="")]) -> int:
    """Score a policy's stored rollouts with trained detectors: AUROC, AUPRC, calibrated rates,
    delays."""
    start = time.perf_counter()
    results = evaluate_policy(cfg)
    print(format_results(results))
    print(f"\n{cfg.out}/results.json ({time.perf_counter() - start:.0f} s)")
    return 0

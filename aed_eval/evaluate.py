"""`aed evaluate`: the paper's main experiment for one task and policy, and more.

The stored novel-split rollouts of a policy (`aed rollout`) are scored offline by every
trained detector; per detector it reports:

- rollout-level AUROC and AUPRC (the paper's accuracy function, 5000 thresholds);
- at the detector's calibrated threshold (`aed calibrate`), when there is one: TPR, TNR,
  balanced accuracy and detection time, as FAIL-Detect and FIPER report them;
- on labelled novel episodes (the experts' injected failures and clean successes, collected
  with `aed collect --split novel`), when given: frame-level AUROC and detection delays.

Two reference rows are computed the same way: `time_only` (score = step / horizon, no input
at all) and `random`. A successful rollout stops at its success while a failed one runs to
the time limit, so under the any-frame rule a score that merely grows with time can look
good; the references show how much of each number is length, and the rollout lengths by
outcome are reported beside them.

Results land in `runs/<task>/<policy>/eval/`: `results.json`, `results.md` and
`scores.json` (every rollout's per-frame scores, for `aed report`'s plots).
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
from aed_eval.calibrate import load_policy_checked, read_calibration
from aed_eval.checks import check_detectors, task_class
from aed_eval.layout import RunLayout
from aed_eval.scoring import (
    DETECTOR_NAMES,
    Demonstrations,
    EpisodeScorer,
    load_checked_detector,
)
from aed_tasks import trajectory

logger = logging.getLogger(__name__)

REFERENCES = ("time_only", "random")


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
    """Labelled expert episodes of the split (default: runs/<task>/data/<split>-labelled, if present)."""
    out: Path | None = None
    """Output folder (default: runs/<task>/<policy>/eval)."""
    num_demos: int = 5
    """Demonstrations per environment given to the detectors."""
    window: int = 10
    """Frames after a labelled onset within which an alarm counts as on time."""
    seed: int = 0
    """Seed of the `random` reference."""
    runs: Path = Path("runs")
    """Root of the runs folder (see aed_eval.layout)."""
    progress: bool = True
    """Show progress bars."""

    def __post_init__(self) -> None:
        from aed_models.policies import POLICIES

        self.task = task_class(self.task).task_name
        if self.policy not in POLICIES:
            raise ValueError(f"policy={self.policy!r}: known {sorted(POLICIES)}")
        check_detectors(self.detectors)
        if self.num_demos < 1 or self.window < 0:
            raise ValueError(f"num_demos={self.num_demos}, window={self.window}: num_demos >= 1, window >= 0")
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
    return {"count": len(v), "min": int(v.min()), "median": float(np.median(v)), "max": int(v.max()),
            "mean": float(v.mean())}  # fmt: skip


def policy_rollouts(root: Path, policy: str) -> tuple[list[trajectory.EpisodeRef], str, int]:
    """The stored rollouts of a policy, its checkpoint sha256 and the episodes' time limit."""
    collection = trajectory.scan_collection(root)
    refs, shas, horizon = [], set(), 0
    for shard in collection.shards:
        horizon = max(horizon, int(shard.body["env_info"].get("max_episode_steps") or 0))
        for entry, ref in zip(shard.body["episodes"], shard.episodes, strict=True):
            if ref.role != "policy_rollout":
                continue
            if entry.get("policy") != policy:
                raise ValueError(f"{shard.json_path}: rollouts of policy {entry.get('policy')!r}, not {policy!r}")
            shas.add(entry.get("policy_sha256"))
            refs.append(ref)
    if not refs:
        raise ValueError(f"{root}: no policy rollouts; run `aed rollout` first")
    if len(shas) != 1:
        raise ValueError(f"{root}: rollouts of {len(shas)} different policy checkpoints; keep one per folder")
    return refs, shas.pop(), horizon


def success_rate(refs: list[trajectory.EpisodeRef]) -> dict[str, Any]:
    """Mean ± std over environments of the per-environment success rate (the paper's table)."""
    per_env: dict[int, list[bool]] = {}
    for ref in refs:
        per_env.setdefault(ref.env_index, []).append(ref.success)
    rates = np.asarray([np.mean(v) for v in per_env.values()])
    return {"mean": float(rates.mean()), "std": float(rates.std()), "num_envs": len(rates),
            "per_env": {str(k): float(np.mean(v)) for k, v in sorted(per_env.items())}}  # fmt: skip


def rollout_metrics(scores: list[np.ndarray], failed: np.ndarray, output: str) -> dict[str, Any]:
    maxima = metrics.rollout_maxima(scores)
    kind = "distance" if output == "distance" else "probability"
    curves = metrics.rollout_curves(maxima, failed, metrics.thresholds(kind, maxima))
    return {"auroc": curves.auroc, "auprc": curves.auprc, "output": output,
            "roc": {"fpr": curves.fpr.tolist()[::50], "tpr": curves.tpr.tolist()[::50]}}  # fmt: skip


def labelled_metrics(scores: list[np.ndarray], refs: list[trajectory.EpisodeRef], threshold: float | None, window: int) -> dict[str, Any]:
    """Frame-level AUROC and, at a threshold, detection delays on episodes with true labels."""
    labels = []
    for ref, s in zip(refs, scores, strict=True):
        frame = np.zeros(len(s), dtype=bool)
        if ref.error_onset is not None:
            frame[int(ref.error_onset) + 1 :] = True  # frame t + 1 follows action t
        labels.append(frame)
    result: dict[str, Any] = {"frame_auroc": metrics.frame_auroc(scores, labels), "episodes": len(refs)}
    failures = [(s, ref) for s, ref in zip(scores, refs, strict=True) if ref.error_onset is not None]
    if threshold is not None and failures:
        result["delays"] = metrics.detection_delays([s for s, _ in failures], [r.error_onset + 1 for _, r in failures],
                                                    threshold, window)  # fmt: skip
    return result


def evaluate_policy(cfg: EvaluateConfig) -> dict[str, Any]:
    """Score every rollout by every detector and compute the metrics (see the module doc)."""
    from tqdm.auto import tqdm

    refs, rollout_sha, horizon = policy_rollouts(Path(cfg.rollouts), cfg.policy)
    layout = RunLayout(cfg.runs)
    policy, policy_sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    if policy_sha != rollout_sha:
        raise ValueError(f"{cfg.rollouts}: rolled out by policy checkpoint {rollout_sha[:12]}, but "
                         f"{layout.policy(cfg.task, cfg.policy)} is {policy_sha[:12]}; re-run aed rollout")  # fmt: skip
    detectors = [load_checked_detector(layout.detector(cfg.task, d, cfg.policy), d, cfg.task, policy_sha)
                 for d in cfg.detectors]  # fmt: skip
    roots = [Path(cfg.demos)] + ([Path(cfg.labelled)] if cfg.labelled is not None else [])
    scorer = EpisodeScorer(detectors, policy, Demonstrations(roots, cfg.split, cfg.num_demos))
    per_detector: dict[str, list[np.ndarray]] = {d.name: [] for d in detectors}
    for ref in tqdm(refs, desc=f"score {cfg.policy} rollouts", disable=not cfg.progress):
        for name, s in scorer.score(ref).items():
            per_detector[name].append(s)
    failed = np.asarray([not r.success for r in refs])
    lengths = [r.num_frames for r in refs]

    labelled_refs: list[trajectory.EpisodeRef] = []
    labelled_scores: dict[str, list[np.ndarray]] = {d.name: [] for d in detectors}
    if cfg.labelled is not None:
        labelled_refs = [e for e in trajectory.scan_collection(Path(cfg.labelled)).episodes()
                         if e.role in ("agent_success", "agent_failure")]  # fmt: skip
        for ref in tqdm(labelled_refs, desc="score labelled episodes", disable=not cfg.progress):
            for name, s in scorer.score(ref).items():
                labelled_scores[name].append(s)
    scorer.close()

    results: dict[str, Any] = {
        "task": cfg.task, "policy": cfg.policy, "policy_sha256": policy_sha, "split": cfg.split,
        "rollouts": {"count": len(refs), "failures": int(failed.sum()), "success_rate": success_rate(refs),
                     "horizon": horizon, "lengths": {"success": stats([n for n, f in zip(lengths, failed, strict=True) if not f]),
                                                     "failure": stats([n for n, f in zip(lengths, failed, strict=True) if f])}},
        "detectors": {}, "references": {},
    }  # fmt: skip
    for d in detectors:
        row = rollout_metrics(per_detector[d.name], failed, d.output)
        calibration = read_calibration(d.path, d.model.checkpoint_sha256)
        threshold = None if calibration is None else float(calibration["threshold"])
        if threshold is not None:
            row["calibrated"] = {"alpha": calibration["alpha"], **metrics.alarm_rates(per_detector[d.name], failed, threshold).to_dict()}
        if labelled_refs:
            row["labelled"] = labelled_metrics(labelled_scores[d.name], labelled_refs, threshold, cfg.window)
        results["detectors"][d.name] = row
    references = {"time_only": metrics.time_only_scores(lengths, horizon), "random": metrics.random_scores(lengths, cfg.seed)}
    for name, scores in references.items():
        results["references"][name] = rollout_metrics(scores, failed, "probability")
    write_results(Path(cfg.out), results, {"rollouts": (refs, per_detector), "labelled": (labelled_refs, labelled_scores)})
    return results


def write_results(out: Path, results: dict[str, Any], scored: dict[str, tuple[list, dict[str, list[np.ndarray]]]]) -> None:
    """results.json, results.md, and scores.json (per-frame scores of every scored episode)."""
    out.mkdir(parents=True, exist_ok=True)
    trajectory.write_json_atomic(out / "results.json", results)
    trajectory.write_json_atomic(out / "scores.json", {
        group: {
            "episodes": [{"env_index": r.env_index, "seed": r.seed, "success": r.success, "role": r.role,
                          "onset_frame": None if r.error_onset is None else int(r.error_onset) + 1} for r in refs],
            "scores": {name: [np.round(s, 6).tolist() for s in values] for name, values in scores.items()},
        }
        for group, (refs, scores) in scored.items()
    })  # fmt: skip
    (out / "results.md").write_text(format_results(results) + "\n")


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}f}"


def format_results(results: dict[str, Any]) -> str:
    r = results["rollouts"]
    sr = r["success_rate"]
    lines = [
        f"## {results['task']} / {results['policy']} ({results['split']} split)",
        "",
        f"Policy success rate {100 * sr['mean']:.1f} ± {100 * sr['std']:.1f}% over {sr['num_envs']} environments "
        f"({r['count']} rollouts, {r['failures']} failed). Frames per rollout: successes median "
        f"{r['lengths']['success'].get('median', '-')}, failures median {r['lengths']['failure'].get('median', '-')} "
        f"(time limit {r['horizon']} steps).",
        "",
        "| detector | AUROC | AUPRC | TPR | TNR | bal. acc. | frame AUROC (labelled) | delays early/on time/late/missed |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    rows = [*results["detectors"].items(), *((f"*{k}*", v) for k, v in results["references"].items())]
    for name, row in rows:
        cal = row.get("calibrated", {})
        lab = row.get("labelled", {})
        delays = lab.get("delays", {}).get("counts")
        delay_text = "/".join(str(delays[k]) for k in metrics.DELAY_CLASSES) if delays else "-"
        lines.append(f"| {name} | {_f(row['auroc'])} | {_f(row['auprc'])} | {_f(cal.get('tpr'), 2)} | "
                     f"{_f(cal.get('tnr'), 2)} | {_f(cal.get('balanced_accuracy'), 2)} | {_f(lab.get('frame_auroc'))} | "
                     f"{delay_text} |")  # fmt: skip
    return "\n".join(lines)


def evaluate(cfg: Annotated[EvaluateConfig, tyro.conf.arg(name="")]) -> int:
    """Score a policy's stored rollouts with trained detectors: AUROC, AUPRC, calibrated rates, delays."""
    start = time.perf_counter()
    results = evaluate_policy(cfg)
    print(format_results(results))
    print(f"\n{cfg.out}/results.json ({time.perf_counter() - start:.0f} s)")
    return 0

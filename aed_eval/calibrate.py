"""`aed calibrate`: alarm thresholds with a promised false-alarm rate (beyond the paper).

The paper sweeps thresholds; a robot team needs one, calibrated on what is deployed: the
policy's own successful rollouts in base environments that neither the policy nor the detector
trained on (the expert's successes look unlike the policy's). Per detector and `alpha`, the
split-conformal threshold on those rollouts' maximum scores (`metrics.conformal_threshold`)
bounds a new success's false-alarm probability by `alpha`. `--source expert` calibrates on the
expert's successes instead (`calibration-expert.json`), to show what that costs. Each file is
tied to the detector's and the policy's checkpoint hashes, and no environment either trained on
is used.
"""

from __future__ import annotations

import json
import logging
import math
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro

from aed_eval import metrics
from aed_eval.checks import check_detectors, check_held_out, task_class, trained_envs
from aed_eval.scoring import (
    DETECTOR_NAMES,
    Demonstrations,
    EpisodeScorer,
    LoadedDetector,
    load_checked_detector,
)
from aed_models.layout import RunLayout
from aed_tasks import trajectory
from aed_tasks.locks import folder_lock

logger = logging.getLogger(__name__)

SOURCES = ("policy", "expert")
FILES = {"policy": "calibration.json", "expert": "calibration-expert.json"}


@dataclass
class CalibrateConfig:
    """Which detectors to calibrate, on what, and for which false-alarm rates."""

    task: str = "PressButton"
    """Task name."""
    policy: str = "naive_dc"
    """The policy the detectors watch (policy-dependent detectors are per policy)."""
    detectors: tuple[str, ...] = DETECTOR_NAMES
    """Detectors to calibrate."""
    alphas: tuple[float, ...] = (0.1, 0.2)
    """Largest tolerated rates of false alarms on successful rollouts (one threshold each)."""
    source: Literal["policy", "expert"] = "policy"
    """policy: the policy's successful rollouts in held-out base environments; expert: the
    expert's agent successes of the base collection (the earlier protocol, for comparison)."""
    rollouts: Path | None = None
    """The policy's base-split rollouts (default: runs/<task>/rollouts/<policy>/base)."""
    data: Path | None = None
    """Base collection: the demonstrations, and the expert successes
    (default: runs/<task>/data/base)."""
    envs: tuple[int, ...] = ()
    """Calibration environments (default: every one of the source that no model trained on)."""
    num_demos: int = 5
    """Demonstrations per environment given to the detectors."""
    allow_trained_envs: bool = False
    """Calibrate on environments a model trained on (a diagnostic; the file says so)."""
    runs: Path = Path("runs")
    """Root of the runs folder (see aed_models.layout)."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self) -> None:
        from aed_models.policies import POLICIES

        self.task = task_class(self.task).task_name
        POLICIES.check(self.policy)
        check_detectors(self.detectors)
        if self.source not in SOURCES:
            raise ValueError(f"source={self.source!r}: known {SOURCES}")
        if not self.alphas or not all(0.0 < a < 1.0 for a in self.alphas):
            raise ValueError(f"alphas={self.alphas}: each must lie in (0, 1)")
        if self.num_demos < 1:
            raise ValueError(f"num_demos={self.num_demos}: must be >= 1")
        layout = RunLayout(self.runs)
        self.data = Path(self.data or layout.data(self.task, "base"))
        self.rollouts = Path(self.rollouts or layout.rollouts(self.task, self.policy, "base"))


def load_policy_checked(path: Path) -> tuple[Any, str]:
    """A policy and its checkpoint's sha256 (a clear error when the file is missing)."""
    from aed_models.policies import load_policy

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no policy checkpoint (aed train-policy)")
    policy = load_policy(path)
    return policy, policy.checkpoint_sha256


def read_calibration(
    detector_path: Path, detector_sha256: str, source: str = "policy"
) -> dict[str, Any] | None:
    """The stored calibration of a detector from `source`, if any and made for this checkpoint."""
    path = Path(detector_path).parent / FILES[source]
    if not path.exists():
        return None
    try:
        body = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(
            f"{path}: corrupt calibration ({e}); delete it and re-run aed calibrate"
        ) from e
    if not isinstance(body, dict) or not isinstance(body.get("thresholds"), dict):
        raise ValueError(
            f"{path}: not an `aed calibrate` file (no thresholds); "
            "delete it and re-run aed calibrate"
        )
    if body.get("detector_sha256") != detector_sha256:
        logger.warning(
            "%s: made for another checkpoint of the detector; ignored (re-run aed calibrate)", path
        )
        return None
    return body


def threshold_at(calibration: dict[str, Any], alpha: float) -> float | None:
    """The calibrated threshold for `alpha` (None: too few successes to promise it)."""
    value = calibration["thresholds"].get(str(alpha))
    return None if value is None else float(value)


def calibration_episodes(cfg: CalibrateConfig, policy_sha: str) -> list[trajectory.EpisodeRef]:
    """The source's episodes: the policy's base rollouts (successful or not), or the expert's
    successes."""
    from aed_eval.rollout import stored_rollouts

    if cfg.source == "policy":
        return stored_rollouts(
            Path(cfg.rollouts),
            cfg.policy,
            policy_sha,
            hint=f"`aed rollout --task {cfg.task} --policy {cfg.policy} --split base`",
        ).refs
    episodes = trajectory.scan_collection(Path(cfg.data)).episodes()
    return [e for e in episodes if e.role == "agent_success" and e.split == "base"]


def finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def needed(alpha: float) -> int:
    """Fewest calibration successes for which a finite threshold promises `alpha`."""
    return math.ceil(1 / alpha) - 1


def calibrate_detectors(cfg: CalibrateConfig) -> dict[str, dict[str, Any]]:
    """Score the held-out successes by every detector; write each detector's thresholds.

    Each detector's folder is locked meanwhile: a training writing there refuses, or is refused.
    """
    layout = RunLayout(cfg.runs)
    policy, policy_sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    detectors = [
        load_checked_detector(
            layout.detector(cfg.task, name, cfg.policy), name, cfg.task, policy_sha
        )
        for name in cfg.detectors
    ]
    with ExitStack() as held:
        for d in detectors:
            held.enter_context(folder_lock(d.path.parent))
        return _calibrate(cfg, policy, policy_sha, detectors)


def _calibrate(
    cfg: CalibrateConfig, policy: Any, policy_sha: str, detectors: list[LoadedDetector]
) -> dict[str, dict[str, Any]]:
    from tqdm.auto import tqdm

    models = {
        f"policy {cfg.policy}": policy.checkpoint_extra,
        **{f"detector {d.name}": d.model.checkpoint_extra for d in detectors},
    }
    episodes = calibration_episodes(cfg, policy_sha)
    if cfg.envs:
        envs = sorted(cfg.envs)
    else:  # every environment of the source that no model trained on
        trained = set().union(*(trained_envs(label, extra)[1] for label, extra in models.items()))
        envs = sorted(
            {e.env_index for e in episodes} - (set() if cfg.allow_trained_envs else trained)
        )
    overlaps = check_held_out(models, "base", envs, "calibrate", cfg.allow_trained_envs)
    refs = [e for e in episodes if e.env_index in envs and e.success]
    if not refs:
        logger.warning(
            "calibrate %s: no successful %s episodes in held-out base environments %s; "
            "no threshold",
            cfg.policy,
            cfg.source,
            envs,
        )
    maxima: dict[str, list[float]] = {d.name: [] for d in detectors}
    if refs:
        scorer = EpisodeScorer(
            detectors, policy, Demonstrations(Path(cfg.data), "base", cfg.num_demos)
        )
        for ref in tqdm(
            refs,
            desc=f"calibrate on {cfg.policy}'s {cfg.source} successes",
            disable=not cfg.progress,
        ):
            for name, scores in scorer.score(ref).items():
                maxima[name].append(float(scores.max()))
        scorer.close()
    results = {}
    for d in detectors:
        values = np.asarray(maxima[d.name])
        thresholds = {
            str(a): finite_or_none(metrics.conformal_threshold(values, a)) if len(values) else None
            for a in cfg.alphas
        }
        short = [a for a in cfg.alphas if thresholds[str(a)] is None]
        if short and refs:
            logger.warning(
                "%s: %d calibration successes cannot promise alpha %s (needs >= %s): "
                "no threshold there",
                d.name,
                len(values),
                short,
                [needed(a) for a in short],
            )
        body = {
            "detector": d.name,
            "source": cfg.source,
            "thresholds": thresholds,
            "num_rollouts": len(values),
            "of_rollouts": sum(e.env_index in envs for e in episodes),
            "envs": envs,
            "episodes": str(cfg.rollouts if cfg.source == "policy" else cfg.data),
            "detector_sha256": d.model.checkpoint_sha256,
            "policy_sha256": policy_sha,
            "diagnostic": bool(overlaps),
            "trained_env_overlap": overlaps,
        }
        trajectory.write_json_atomic(d.path.parent / FILES[cfg.source], body)
        results[d.name] = body
    return results


def calibrate(
    cfg: Annotated[CalibrateConfig, tyro.conf.arg(name="")],
    output: Literal["text", "json"] = "text",
) -> int:
    """Pick each detector's alarm thresholds for false-alarm rates <= alpha (split conformal)."""
    results = calibrate_detectors(cfg)
    if output == "json":
        print(json.dumps(results, indent=2))
        return 0
    for name, body in results.items():
        cells = ", ".join(
            f"alpha {a}: {'-' if t is None else f'{t:.4g}'}" for a, t in body["thresholds"].items()
        )
        flag = " (DIAGNOSTIC: environments a model trained on)" if body["diagnostic"] else ""
        print(
            f"{name}: {cells} from {body['num_rollouts']} {cfg.source} successes (of "
            f"{body['of_rollouts']} episodes) in base environments {body['envs']}{flag}"
        )
    return 0

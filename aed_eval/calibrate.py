"""`aed calibrate`: an alarm threshold with a promised false-alarm rate (beyond the paper).

The paper sweeps thresholds; a robot team needs one. For each detector, successful base-split
rollouts of environments held out of the detector's training (the agent successes of the
base collection's remaining environments) are scored; the split-conformal threshold on their
maximum scores (`aed_eval.metrics.conformal_threshold`) makes a new successful rollout raise
a false alarm with probability at most `alpha`, as long as it is exchangeable with them.
The threshold is stored beside the detector as `calibration.json`, tied to the detector's
and the policy's checkpoint hashes.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro

from aed_eval import metrics
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

CALIBRATION = "calibration.json"


@dataclass
class CalibrateConfig:
    """Which detectors to calibrate, on what, and for which false-alarm rate."""

    task: str = "PressButton"
    """Task name."""
    policy: str = "naive_dc"
    """The policy the detectors watch (policy-dependent detectors are per policy)."""
    detectors: tuple[str, ...] = DETECTOR_NAMES
    """Detectors to calibrate."""
    alpha: float = 0.1
    """Largest tolerated rate of false alarms on successful rollouts."""
    data: Path | None = None
    """Base collection (default: runs/<task>/data/base)."""
    envs: tuple[int, ...] = ()
    """Calibration environments (default: the collection's environments the detector never saw)."""
    num_demos: int = 5
    """Demonstrations per environment given to the detectors."""
    runs: Path = Path("runs")
    """Root of the runs folder (see aed_eval.layout)."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self) -> None:
        self.task = task_class(self.task).task_name
        check_detectors(self.detectors)
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha={self.alpha}: must lie in (0, 1)")
        if self.num_demos < 1:
            raise ValueError(f"num_demos={self.num_demos}: must be >= 1")
        self.data = Path(self.data or RunLayout(self.runs).data(self.task, "base"))


def load_policy_checked(path: Path) -> tuple[Any, str]:
    """A policy and its checkpoint's sha256 (a clear error when the file is missing)."""
    from aed_models.checkpoint import file_sha256
    from aed_models.policies import load_policy

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no policy checkpoint (aed train-policy)")
    return load_policy(path).eval(), file_sha256(path)


def held_out_envs(model: Any, collection_envs: list[int]) -> list[int]:
    """Environments of the collection that the detector's training did not use."""
    train_config = (getattr(model, "checkpoint_extra", {}) or {}).get("train_config", {})
    num_envs = train_config.get("num_envs")
    trained = set(collection_envs if num_envs is None else sorted(collection_envs)[:num_envs])
    return [e for e in collection_envs if e not in trained]


def read_calibration(detector_path: Path, detector_sha256: str) -> dict[str, Any] | None:
    """The stored calibration of a detector, if any and if made for this very checkpoint."""
    path = Path(detector_path).parent / CALIBRATION
    if not path.exists():
        return None
    try:
        body = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: corrupt calibration ({e}); delete it and re-run aed calibrate") from e
    if body.get("detector_sha256") != detector_sha256:
        logger.warning("%s: made for another checkpoint of the detector; ignored (re-run aed calibrate)", path)
        return None
    return body


def calibrate_detectors(cfg: CalibrateConfig) -> dict[str, dict[str, Any]]:
    from tqdm.auto import tqdm

    layout = RunLayout(cfg.runs)
    policy, policy_sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    episodes = trajectory.scan_collection(Path(cfg.data)).episodes()
    successes = [e for e in episodes if e.role == "agent_success" and e.split == "base"]
    collection_envs = sorted({e.env_index for e in episodes})
    results = {}
    for name in cfg.detectors:
        path = layout.detector(cfg.task, name, cfg.policy)
        detector = load_checked_detector(path, name, cfg.task, policy_sha)
        envs = list(cfg.envs) or held_out_envs(detector.model, collection_envs)
        refs = [e for e in successes if e.env_index in envs]
        if not refs:
            raise ValueError(f"{name}: no held-out successful base episodes in {cfg.data} (environments {envs}); "
                             "collect more base environments than the detector trains on, or pass --envs")  # fmt: skip
        scorer = EpisodeScorer([detector], policy, Demonstrations(Path(cfg.data), "base", cfg.num_demos))
        maxima = np.asarray([
            scorer.score(ref)[name].max() for ref in tqdm(refs, desc=f"calibrate {name}", disable=not cfg.progress)
        ])  # fmt: skip
        scorer.close()
        threshold = metrics.conformal_threshold(maxima, cfg.alpha)
        body = {
            "detector": name, "alpha": cfg.alpha, "threshold": threshold, "num_rollouts": len(maxima), "envs": envs,
            "source": str(cfg.data), "detector_sha256": detector.model.checkpoint_sha256, "policy_sha256": policy_sha,
        }  # fmt: skip
        if not np.isfinite(threshold):
            logger.warning("%s: %d calibration rollouts cannot promise alpha=%.3g (needs >= %d): never alarms",
                           name, len(maxima), cfg.alpha, int(np.ceil(1 / cfg.alpha)) - 1)  # fmt: skip
        trajectory.write_json_atomic(path.parent / CALIBRATION, body)
        results[name] = body
    return results


def calibrate(cfg: Annotated[CalibrateConfig, tyro.conf.arg(name="")], output: Literal["text", "json"] = "text") -> int:
    """Pick each detector's alarm threshold for a false-alarm rate <= alpha (split conformal)."""
    results = calibrate_detectors(cfg)
    if output == "json":
        print(json.dumps(results, indent=2))
    for name, body in results.items():
        if output == "text":
            print(f"{name}: threshold {body['threshold']:.4g} from {body['num_rollouts']} held-out successes "
                  f"(alpha {body['alpha']}, environments {body['envs']})")  # fmt: skip
    return 0

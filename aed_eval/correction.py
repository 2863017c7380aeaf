"""The paper's error-correction pilot: a policy's stored novel rollouts replayed with a detector
beside it (`AEDMonitor`); at its first alarm (threshold 0.9, the paper's) the TCP goes to a
safe pose above the table centre and the policy takes over again.

Each replay uses the stored rollout's environment and seed, so until the first alarm it is the
stored rollout again: the stored outcomes are the "without a detector" column, paired rollout
by rollout with each detector's. A replay the detector never alarmed on must end as the stored
one did; the record counts those that did not (0 when the simulation replays exactly).
Finished detectors are kept in `<runs>/<task>/<policy>/correction/<detector>.json`, so a
stopped run resumes at the next one.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aed_eval import paper
from aed_eval.scoring import DETECTOR_NAMES
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import trajectory

logger = logging.getLogger(__name__)


@dataclass
class CorrectionConfig:
    """The pilot of one (task, policy).

    Args:
        task: task name.
        policy: the policy whose novel rollouts are replayed.
        detectors: detectors tried, one after another.
        threshold: alarm threshold of every detector (the paper's 0.9).
        num_demos: demonstrations the policy and the detectors are conditioned on.
        max_rollouts: replay the first N stored rollouts only (0: all).
        profile: the profile of the runs.
        runs: runs folder (the layout of aed_models.layout; default runs/<profile>).
        out: folder of the record (default results/<profile>/error_correction).
    """

    task: str = "PressButton"
    policy: str = "dct"
    detectors: tuple[str, ...] = DETECTOR_NAMES
    threshold: float = 0.9
    num_demos: int = 5
    max_rollouts: int = 0
    profile: Profile = "mini"
    runs: Path | None = None
    out: Path | None = None

    def __post_init__(self) -> None:
        from aed_eval.checks import check_detectors, task_class

        self.task = task_class(self.task).task_name
        check_detectors(self.detectors)
        if self.num_demos < 1 or self.max_rollouts < 0:
            raise ValueError(f"num_demos={self.num_demos} >= 1, max_rollouts >= 0 expected")
        check_profile(self.profile)
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile
        self.out = (
            Path(self.out)
            if self.out is not None
            else Path("results") / self.profile / "error_correction"
        )


def replay(monitor: Any, env_index: int, seed: int, horizon: int) -> dict[str, Any]:
    """One corrected rollout: success (latched), alarms and the step of the first one."""
    _, info = monitor.reset(seed=seed, options={"env_index": env_index})
    success, first_alarm = False, 0 if info["aed_alarm"] else None
    steps = 0
    while steps < horizon:
        _, _, _, truncated, info = monitor.step(None)
        steps = int(np.asarray(monitor.unwrapped.elapsed_steps).reshape(-1)[0])
        success |= bool(np.asarray(info["success"]).any())
        if info["aed_alarm"] and first_alarm is None:
            first_alarm = steps
        if np.asarray(truncated).any():
            break
    return {
        "env_index": env_index,
        "seed": seed,
        "success": success,
        "first_alarm": first_alarm,
        "corrections": int(info["aed_corrections"]),
    }


def run_detector(cfg: CorrectionConfig, detector: str, refs: list, horizon: int) -> list[dict]:
    """Every replay with one detector beside the policy."""
    import gymnasium as gym

    import aed_tasks
    from aed_eval.calibrate import load_policy_checked
    from aed_eval.monitor import AEDMonitor
    from aed_eval.scoring import Demonstrations, load_checked_detector

    layout = RunLayout(cfg.runs)
    policy, sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    loaded = load_checked_detector(
        layout.detector(cfg.task, detector, cfg.policy), detector, cfg.task, sha
    )
    demos = Demonstrations(layout.data(cfg.task, "novel"), "novel", cfg.num_demos)
    env = gym.make(
        aed_tasks.env_id(cfg.task, "novel"),
        obs_mode="rgbd",
        max_episode_steps=horizon,
        terminate_on_success=False,
    )
    results = []
    try:
        for ref in refs:
            monitor = AEDMonitor(
                env, policy, loaded.model, demos[ref.env_index], cfg.threshold, "correct"
            )
            results.append(
                {**replay(monitor, ref.env_index, ref.seed, horizon), "was": ref.success}
            )
    finally:
        env.close()
    return results


def correction_record(cfg: CorrectionConfig) -> dict[str, Any]:
    """Replay with every detector (resuming finished ones); the pilot's record."""
    from aed_eval.calibrate import load_policy_checked
    from aed_eval.rollout import stored_rollouts

    layout = RunLayout(cfg.runs)
    _, sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    stored = stored_rollouts(layout.rollouts(cfg.task, cfg.policy, "novel"), cfg.policy, sha)
    refs = sorted(stored.refs, key=lambda r: (r.env_index, r.seed))
    refs = refs[: cfg.max_rollouts] if cfg.max_rollouts else refs
    folder = layout.evaluation(cfg.task, cfg.policy).parent / "correction"
    folder.mkdir(parents=True, exist_ok=True)
    key = {"policy_sha256": sha, "threshold": cfg.threshold, "rollouts": len(refs)}
    detectors = {}
    for detector in cfg.detectors:
        path = folder / f"{detector}.json"
        kept = json.loads(path.read_text()) if path.exists() else None
        if kept is None or kept.get("key") != key:
            logger.info("correction: %s / %s with %s", cfg.task, cfg.policy, detector)
            kept = {"key": key, "replays": run_detector(cfg, detector, refs, stored.horizon)}
            trajectory.write_json_atomic(path, kept)
        detectors[detector] = summary(kept["replays"])
    return {
        "kind": "error_correction",
        "task": cfg.task,
        "policy": cfg.policy,
        "policy_sha256": sha,
        "threshold": cfg.threshold,
        "horizon": stored.horizon,
        "rollouts": len(refs),
        "successes_without": int(sum(r.success for r in refs)),
        "detectors": detectors,
        "paper": paper.correction_numbers(cfg.task, cfg.policy),
    }


def summary(replays: list[dict]) -> dict[str, Any]:
    """Successes with the detector, alarms, and the pairing with the stored outcomes."""
    quiet = [r for r in replays if r["first_alarm"] is None]
    return {
        "successes": int(sum(r["success"] for r in replays)),
        "alarmed": len(replays) - len(quiet),
        "alarmed_on_success": int(sum(r["was"] for r in replays if r["first_alarm"] is not None)),
        "only_without": int(sum(r["was"] and not r["success"] for r in replays)),
        "only_with": int(sum(r["success"] and not r["was"] for r in replays)),
        "quiet_replays_changed": int(sum(r["success"] != r["was"] for r in quiet)),
    }

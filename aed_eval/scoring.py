"""Offline scoring of stored episodes by trained detectors (shared by evaluate and calibrate).

A detector (found through `aed_eval.layout.RunLayout`) is checked before it scores anything: trained for this task, and, when it reads a policy's
features, trained on exactly this policy checkpoint (same sha256). Policy features of an
episode are computed once and shared by every policy-dependent detector.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aed_tasks import trajectory

logger = logging.getLogger(__name__)

DETECTOR_NAMES = ("svdd_ed", "taskemb_ed", "lstm_ed", "dct_ed", "probe", "rnd_oe")


@dataclass
class LoadedDetector:
    name: str
    model: Any
    path: Path

    @property
    def output(self) -> str:
        return self.model.output


def load_checked_detector(path: Path, name: str, task: str, policy_sha256: str) -> LoadedDetector:
    """Load a detector and refuse one trained for another task or another policy checkpoint."""
    from aed_models.detectors import load_detector

    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no {name} checkpoint; train it with `aed train-detector --task {task} "
                                f"--detector {name}`")  # fmt: skip
    model = load_detector(path, name=name)
    extra = getattr(model, "checkpoint_extra", {}) or {}
    if extra.get("task") not in (None, task):
        raise ValueError(f"{path}: {name} was trained for task {extra.get('task')!r}, not {task!r}")
    if model.requires_policy and extra.get("policy_sha256") != policy_sha256:
        raise ValueError(f"{path}: {name} was trained on policy {extra.get('policy_name')!r} "
                         f"({str(extra.get('policy_sha256'))[:12]}), not on the evaluated checkpoint "
                         f"({policy_sha256[:12]}); retrain it with --policy")  # fmt: skip
    return LoadedDetector(name, model.eval(), Path(path))


class EpisodeScorer:
    """Scores episodes with several detectors; frames read and policy features computed once."""

    def __init__(self, detectors: Sequence[LoadedDetector], policy: Any, demos: dict[int, dict[str, Any]]):
        from aed_models.data import EpisodeReader

        self.detectors = list(detectors)
        self.policy = policy
        self.demos = demos
        self.reader = EpisodeReader()

    def close(self) -> None:
        self.reader.close()

    @torch.inference_mode()
    def score(self, ref: trajectory.EpisodeRef) -> dict[str, np.ndarray]:
        """Per-frame scores (T + 1,) of one stored episode by every detector."""
        from aed_models.data import pad_sequences

        if ref.env_index not in self.demos:
            raise ValueError(f"{ref.path}:{ref.traj}: no demonstrations of environment {ref.env_index}")
        demos = self.demos[ref.env_index]
        rollout = pad_sequences([self.reader.read(ref)])
        features = None
        if any(d.model.requires_policy for d in self.detectors):
            features = self.policy.features(rollout["frames"], rollout["mask"], demos)
        return {
            d.name: d.model.score(rollout, demos, features if d.model.requires_policy else None)[0].cpu().numpy().astype(np.float64)
            for d in self.detectors
        }


def demonstrations_by_env(root: Path, split: str, num_demos: int, env_indices: Sequence[int] | None = None) -> dict[int, dict[str, Any]]:
    """The first `num_demos` optimal demonstrations of each environment, padded."""
    from aed_models.data import EpisodeReader, pad_sequences

    refs: dict[int, list[trajectory.EpisodeRef]] = {}
    for ref in trajectory.scan_collection(root).episodes():
        if ref.role == "demo" and not ref.suboptimal and ref.split == split:
            if env_indices is None or ref.env_index in env_indices:
                refs.setdefault(ref.env_index, []).append(ref)
    reader = EpisodeReader()
    try:
        return {env: pad_sequences([reader.read(r) for r in group[:num_demos]]) for env, group in sorted(refs.items())}
    finally:
        reader.close()

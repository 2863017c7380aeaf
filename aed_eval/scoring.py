"""Offline scoring of stored episodes by trained detectors (shared by evaluate and calibrate).

A detector (found through `aed_models.layout.RunLayout`) is checked before it scores anything:
trained for this task, and, when it reads a policy's features, trained on exactly this policy
checkpoint (same sha256). Policy features of an episode are computed once and shared by every
policy-dependent detector."""

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
PAPER_DETECTORS = DETECTOR_NAMES[:5]  # the paper's five: the only ones its summary rows rank


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
        raise FileNotFoundError(
            f"{path}: no {name} checkpoint; train it with `aed train-detector --task {task} "
            f"--detector {name}`"
        )
    model = load_detector(path, name=name)
    extra = getattr(model, "checkpoint_extra", {}) or {}
    if extra.get("task") not in (None, task):
        raise ValueError(f"{path}: {name} was trained for task {extra.get('task')!r}, not {task!r}")
    if model.requires_policy and extra.get("policy_sha256") != policy_sha256:
        raise ValueError(
            f"{path}: {name} was trained on policy {extra.get('policy_name')!r} "
            f"({str(extra.get('policy_sha256'))[:12]}), not on the evaluated checkpoint "
            f"({policy_sha256[:12]}); retrain it with --policy"
        )
    return LoadedDetector(name, model.eval(), Path(path))


class EpisodeScorer:
    """Scores episodes with several detectors: each episode's frames read and policy features
    computed once, each environment's demonstrations read by every detector once (`prepare`;
    score episodes environment by environment)."""

    def __init__(self, detectors: Sequence[LoadedDetector], policy: Any, demos: Demonstrations):
        from aed_models.data import EpisodeReader

        self.detectors = list(detectors)
        self.policy = policy
        self.demos = demos
        self.reader = EpisodeReader(demos.camera)  # the camera the demonstrations were seen by
        self._prepared: tuple[int, dict[str, Any]] | None = None

    def close(self) -> None:
        self.reader.close()

    def _prepared_demos(self, env_index: int) -> dict[str, Any]:
        """Each detector's `prepare` of the environment's demonstrations (the latest kept)."""
        if self._prepared is None or self._prepared[0] != env_index:
            demos = self.demos[env_index]
            self._prepared = (env_index, {d.name: d.model.prepare(demos) for d in self.detectors})
        return self._prepared[1]

    def _inputs(self, ref: trajectory.EpisodeRef) -> tuple[dict, dict, Any]:
        """(rollout batch of one, its environment's demonstrations, the policy's features or
        None) of one stored episode."""
        from aed_models.data import pad_sequences

        if ref.env_index not in self.demos:
            raise ValueError(
                f"{ref.path}:{ref.traj}: no demonstrations of environment {ref.env_index}"
            )
        demos = self.demos[ref.env_index]
        rollout = pad_sequences([self.reader.read(ref)])
        features = None
        if any(d.model.requires_policy for d in self.detectors):
            features = self.policy.features(
                rollout["frames"], rollout["mask"], demos, proprio=rollout.get("proprio")
            )
        return rollout, demos, features

    @torch.inference_mode()
    def score(self, ref: trajectory.EpisodeRef) -> dict[str, np.ndarray]:
        """Per-frame scores (T + 1,) of one stored episode by every detector, post-processed as
        online (`aed_models.detectors.postprocess`)."""
        rollout, _, features = self._inputs(ref)
        prepared = self._prepared_demos(ref.env_index)
        return {
            d.name: self._scores(d, rollout, prepared[d.name], features) for d in self.detectors
        }

    @torch.inference_mode()
    def embed(self, ref: trajectory.EpisodeRef) -> dict[str, np.ndarray]:
        """Per-frame embeddings (T + 1, E) of one stored episode by every detector
        (`ErrorDetector.embed`)."""
        rollout, _, features = self._inputs(ref)
        prepared = self._prepared_demos(ref.env_index)
        return {
            d.name: d.model.embed(
                rollout, prepared[d.name], features if d.model.requires_policy else None
            )[0]
            .cpu()
            .numpy()
            for d in self.detectors
        }

    @staticmethod
    def _scores(
        d: LoadedDetector, rollout: dict[str, Any], demos: Any, features: Any
    ) -> np.ndarray:
        """One detector's post-processed scores (T + 1,) of a batch of one rollout."""
        from aed_models.detectors.postprocess import postprocess

        per_frame = d.model.score(rollout, demos, features if d.model.requires_policy else None)
        scores = postprocess(d.model, per_frame, rollout["mask"])
        return scores[0].cpu().numpy().astype(np.float64)


class Demonstrations:
    """The demonstrations of each environment of one or more collections: the first
    `num_demos - num_suboptimal` optimal ones, then the first `num_suboptimal` sub-optimal ones
    (a failed first attempt, then success), read when first asked for and padded (`frames`,
    `mask`), through `camera` (`front_shift`: the viewpoint-shift experiment).

    Only the latest environment's frames are kept: as float tensors 5 demonstrations of about
    100 frames take ~150 MB, so holding every novel environment's would take gigabytes, while
    rollouts and episodes are read environment by environment.
    """

    def __init__(
        self,
        roots: Path | Sequence[Path],
        split: str,
        num_demos: int,
        num_suboptimal: int = 0,
        camera: str = "front",
    ):
        if not 0 <= num_suboptimal <= num_demos:
            raise ValueError(f"num_suboptimal={num_suboptimal}: 0..num_demos={num_demos}")
        roots = [roots] if isinstance(roots, (str, Path)) else list(roots)
        self.num_demos, self.num_suboptimal, self.camera = num_demos, num_suboptimal, camera
        optimal: dict[int, list[trajectory.EpisodeRef]] = {}
        suboptimal: dict[int, list[trajectory.EpisodeRef]] = {}
        for root in roots:
            for ref in trajectory.scan_collection(Path(root)).episodes():
                if ref.role == "demo" and ref.split == split:
                    kind = suboptimal if ref.suboptimal else optimal
                    kind.setdefault(ref.env_index, []).append(ref)
        self.refs: dict[int, list[trajectory.EpisodeRef]] = {}
        short = []
        for env in sorted(optimal.keys() | suboptimal.keys()):
            picked = optimal.get(env, [])[: num_demos - num_suboptimal]
            picked += suboptimal.get(env, [])[:num_suboptimal]
            if num_suboptimal and len(picked) < num_demos:
                short.append(env)
            elif picked:
                self.refs[env] = picked
        if short:
            raise ValueError(
                f"environments {short} of {[str(r) for r in roots]}: fewer than "
                f"{num_demos - num_suboptimal} optimal and {num_suboptimal} sub-optimal "
                "demonstrations; collect them with `aed collect --num-suboptimal-demos ...`"
            )
        self._latest: tuple[int, dict[str, Any]] | None = None

    def envs(self) -> list[int]:
        return sorted(self.refs)

    def __contains__(self, env_index: int) -> bool:
        return env_index in self.refs

    def __getitem__(self, env_index: int) -> dict[str, Any]:
        from aed_models.data import EpisodeReader, pad_sequences

        if self._latest is None or self._latest[0] != env_index:
            reader = EpisodeReader(self.camera)
            try:
                demos = pad_sequences(
                    [reader.read(r) for r in self.refs[env_index][: self.num_demos]]
                )
            finally:
                reader.close()
            self._latest = (env_index, demos)
        return self._latest[1]

"""Embedding visualisation (the paper's t-SNE figure): what each detector's last layer reads,
frame by frame, on labelled novel episodes (expert successes and injected failures), mapped to
2-D by t-SNE and coloured normal or error, darker early in the episode and brighter late.

The picture is read beside two numbers measured in the embeddings themselves (not in the
t-SNE map): of each frame's nearest frames from *other* episodes, the share with its label
(normal or error; "homogeneous state clustering") and their mean progress gap ("task
progress"). Neighbours from the frame's own episode are left out, since consecutive frames are
close whatever the detector learned.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import trajectory

logger = logging.getLogger(__name__)


@dataclass
class EmbeddingsConfig:
    """The embedding figure of one (task, policy).

    Args:
        task: task name.
        policy: the policy PrObe (and rnd_oe) read; the visual detectors do not depend on it.
        detectors: detectors shown (the paper's figure: taskemb_ed, lstm_ed, probe).
        num_episodes: labelled novel episodes, half successes and half failures, the first of
            each in (environment, seed) order.
        num_demos: demonstrations the detectors and the policy are conditioned on.
        neighbours: nearest frames of other episodes in the two numbers.
        perplexity: t-SNE's.
        seed: t-SNE's random state.
        profile: the profile of the runs.
        runs: runs folder (the layout of aed_models.layout; default runs/<profile>).
        out: folder of the record (default results/<profile>/embeddings).
    """

    task: str = "PickPlace"
    policy: str = "scan"
    detectors: tuple[str, ...] = ("taskemb_ed", "lstm_ed", "probe")
    num_episodes: int = 20
    num_demos: int = 5
    neighbours: int = 10
    perplexity: float = 30.0
    seed: int = 0
    profile: Profile = "mini"
    runs: Path | None = None
    out: Path | None = None

    def __post_init__(self) -> None:
        from aed_eval.checks import check_detectors, task_class

        self.task = task_class(self.task).task_name
        check_detectors(self.detectors)
        if self.num_episodes < 2 or self.num_demos < 1 or self.neighbours < 1:
            raise ValueError(
                f"num_episodes={self.num_episodes} >= 2, num_demos={self.num_demos} >= 1 and "
                f"neighbours={self.neighbours} >= 1 expected"
            )
        if self.perplexity <= 0:
            raise ValueError(f"perplexity={self.perplexity}: must be > 0")
        check_profile(self.profile)
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile
        self.out = (
            Path(self.out)
            if self.out is not None
            else Path("results") / self.profile / "embeddings"
        )


def pick_episodes(folder: Path, count: int) -> list[trajectory.EpisodeRef]:
    """The first `count // 2` failures and `count - count // 2` successes of a labelled
    collection, in (environment, seed) order."""
    refs = sorted(
        (
            r
            for r in trajectory.scan_collection(folder).episodes()
            if r.role in ("agent_success", "agent_failure")
        ),
        key=lambda r: (r.env_index, r.seed),
    )
    failures = [r for r in refs if r.error_onset is not None][: count // 2]
    successes = [r for r in refs if r.error_onset is None][: count - count // 2]
    if len(failures) + len(successes) < count:
        raise ValueError(
            f"{folder}: {len(successes)} successes and {len(failures)} labelled failures, "
            f"{count} episodes asked for; collect more with `aed collect --split novel "
            f"--num-successes ... --num-failures ... --out {folder}`"
        )
    return successes + failures


def frame_table(refs: list[trajectory.EpisodeRef]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame of the episodes, concatenated: its episode, its label (after the onset) and
    its progress through the episode (0 at the first frame, 1 at the last)."""
    episode = np.concatenate([np.full(r.num_frames, i) for i, r in enumerate(refs)])
    labels = np.concatenate([r.frame_labels() for r in refs])
    progress = np.concatenate([np.linspace(0.0, 1.0, r.num_frames) for r in refs])
    return episode, labels, progress


def neighbourhood(
    embeddings: np.ndarray, episode: np.ndarray, labels: np.ndarray, progress: np.ndarray, k: int
) -> dict[str, float]:
    """Over every frame's `k` nearest frames (Euclidean) of other episodes: the share with the
    frame's label, that share under random neighbours (chance), and the mean progress gap."""
    x = embeddings.astype(np.float64)
    squared = (x * x).sum(1)
    distances = squared[:, None] + squared[None, :] - 2.0 * x @ x.T
    distances[episode[:, None] == episode[None, :]] = np.inf
    nearest = np.argsort(distances, axis=1)[:, :k]
    same = labels[nearest] == labels[:, None]
    share = labels.mean()
    return {
        "label_agreement": float(same.mean()),
        "chance": float(share**2 + (1 - share) ** 2),
        "progress_gap": float(np.abs(progress[nearest] - progress[:, None]).mean()),
    }


def tsne(embeddings: np.ndarray, perplexity: float, seed: int) -> np.ndarray:
    """(N, 2) t-SNE map of (N, E) embeddings (scikit-learn's, PCA initialisation)."""
    from sklearn.manifold import TSNE

    perplexity = min(perplexity, (len(embeddings) - 1) / 3)
    return TSNE(2, perplexity=perplexity, init="pca", random_state=seed).fit_transform(
        embeddings.astype(np.float64)
    )


def embed_episodes(cfg: EmbeddingsConfig, refs: list[trajectory.EpisodeRef]) -> tuple[dict, str]:
    """Every detector's (N, E) embeddings of the episodes' frames, and the policy's sha256."""
    from aed_eval.calibrate import load_policy_checked
    from aed_eval.scoring import Demonstrations, EpisodeScorer, load_checked_detector

    layout = RunLayout(cfg.runs)
    policy, sha = load_policy_checked(layout.policy(cfg.task, cfg.policy))
    detectors = [
        load_checked_detector(layout.detector(cfg.task, d, cfg.policy), d, cfg.task, sha)
        for d in cfg.detectors
    ]
    demos = Demonstrations(
        [layout.data(cfg.task, "novel"), layout.labelled(cfg.task, "novel")], "novel", cfg.num_demos
    )
    scorer = EpisodeScorer(detectors, policy, demos)
    try:
        per_episode = [scorer.embed(r) for r in refs]
    finally:
        scorer.close()
    return {d: np.concatenate([e[d] for e in per_episode]) for d in cfg.detectors}, sha


def embeddings_record(cfg: EmbeddingsConfig) -> dict[str, Any]:
    """The figure's record: the episodes, and per detector its 2-D map and the two numbers."""
    labelled = RunLayout(cfg.runs).labelled(cfg.task, "novel")
    refs = pick_episodes(labelled, cfg.num_episodes)
    episode, labels, progress = frame_table(refs)
    embedded, sha = embed_episodes(cfg, refs)
    detectors = {}
    for name, x in embedded.items():
        logger.info("embeddings: t-SNE of %s's %d x %d", name, *x.shape)
        points = tsne(x, cfg.perplexity, cfg.seed)
        detectors[name] = {
            "dim": int(x.shape[1]),
            **neighbourhood(x, episode, labels, progress, cfg.neighbours),
            "points": np.round(points, 2).tolist(),
        }
    return {
        "kind": "embeddings",
        "task": cfg.task,
        "policy": cfg.policy,
        "policy_sha256": sha,
        "labelled": str(labelled),
        "neighbours": cfg.neighbours,
        "perplexity": cfg.perplexity,
        "seed": cfg.seed,
        "episodes": [
            {
                "env_index": r.env_index,
                "seed": r.seed,
                "frames": r.num_frames,
                "onset_frame": r.onset_frame,
                "error_kind": r.error_kind,
            }
            for r in refs
        ],
        "detectors": detectors,
    }

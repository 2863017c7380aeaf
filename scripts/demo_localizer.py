"""How far off the target localizer places a novel environment's stage targets, from its
demonstrations alone.

Each novel demonstration's first frame (or every n-th, `--every`) is located from the queries
of its environment's other demonstrations; the error is the horizontal distance to where that
demonstration ended the stage (its TCP), in cm, beside the guess of the training episodes'
mean stage point (`--data`) and, given `--encoder`, the scene encoder's stage-target read-out
on the same frames. 95% bootstrap intervals over demonstrations (a demonstration's frames
resampled together).

    python scripts/demo_localizer.py --localizer runs/PressButton/localizer/localizer.pt \
        --novel runs/PressButton/data/novel --data runs/PressButton/data/base \
        [--encoder runs/PressButton/encoder/encoder.pt] [--every 4] [--depth-window 0] \
        [--out result.json]
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro

from aed_models.data import EpisodeReader, load_episodes
from aed_models.localizer import load_localizer
from aed_models.train.localizer import stage_episode

logger = logging.getLogger("demo_localizer")


@dataclass
class Config:
    localizer: Path = Path("runs/PressButton/localizer/localizer.pt")
    """The trained localizer (`aed train-localizer`)."""
    novel: Path = Path("runs/PressButton/data/novel")
    """Novel collection whose demonstrations are located."""
    data: Path | None = None
    """Base collection the localizer trained on: the mean guess of its training environments."""
    encoder: Path | None = None
    """Also score this scene encoder's stage-target read-out on the same frames."""
    every: int = 1000
    """Locate every n-th frame of each demonstration (the default: its first alone)."""
    depth_window: int | None = None
    """Lift the located pixels with this depth window in place of the checkpoint's."""
    seed: int = 0
    """Seeds the bootstrap."""
    out: Path | None = None
    """Write the results as JSON here."""


@torch.no_grad()
def locate_demonstrations(cfg: Config) -> dict[str, list[np.ndarray]]:
    """Per demonstration, the horizontal errors (m) of its located frames: the localizer's,
    the encoder's (given one) and the training mean's."""
    localizer = load_localizer(cfg.localizer)
    if cfg.depth_window is not None:
        localizer.config = dataclasses.replace(localizer.config, depth_window=cfg.depth_window)
    k = localizer.config.num_targets
    encoder = None
    if cfg.encoder:
        from aed_models.encoder import load_encoder

        encoder = load_encoder(cfg.encoder)
        column = encoder.config.state_names.index("subgoal.x")
    mean_guess = None
    if cfg.data:
        trained = torch.load(cfg.localizer, weights_only=True)["extra"]["train_envs"]
        base = [
            e
            for e in load_episodes(cfg.data, split="base")
            if e.role in ("demo", "agent_success") and e.env_index in trained
        ]
        mean_guess = np.mean([stage_episode(e, k, "front").points for e in base], axis=0)
    demos = [e for e in load_episodes(cfg.novel, split="novel") if e.role == "demo"]
    reader = EpisodeReader()
    errors: dict[str, list[np.ndarray]] = {"localizer": [], "encoder": [], "mean_guess": []}
    for env in sorted({d.env_index for d in demos}):
        infos = [stage_episode(d, k, "front") for d in demos if d.env_index == env]
        firsts = torch.stack([reader.read(i.ref, np.array([0])).frames[0] for i in infos])
        points = torch.from_numpy(np.stack([i.points for i in infos])).float()
        for j, info in enumerate(infos):
            others = [i for i in range(len(infos)) if i != j]
            queries = localizer.queries(firsts[others], points[others])
            frames = reader.read(info.ref, np.arange(0, info.ref.num_frames, cfg.every)).frames
            located = localizer.locate(frames, queries).numpy()  # (n, K, 3)
            truth = info.points[None, :, :2]
            errors["localizer"].append(np.linalg.norm(located[..., :2] - truth, axis=-1).ravel())
            if encoder is not None:  # the read-out of the current stage's target (stage 0 here)
                read = encoder.predict_state(frames)[:, column : column + 2].numpy()
                errors["encoder"].append(np.linalg.norm(read - truth[:, 0], axis=-1))
            if mean_guess is not None:
                guess = np.broadcast_to(mean_guess[None, :, :2], located[..., :2].shape)
                errors["mean_guess"].append(np.linalg.norm(guess - truth, axis=-1).ravel())
        logger.info(
            "novel env %d: median localizer error %.1f cm",
            env,
            100 * np.median(np.concatenate(errors["localizer"][-len(infos) :])),
        )
    reader.close()
    return {name: e for name, e in errors.items() if e}


def summary(per_demo: list[np.ndarray], seed: int, draws: int = 1000) -> dict[str, object]:
    """Mean, median and share within 3 cm of the errors (cm), with 95% bootstrap intervals
    over demonstrations."""

    def stats(arrays: list[np.ndarray]) -> np.ndarray:
        e = np.concatenate(arrays)
        return np.array([100 * e.mean(), 100 * np.median(e), (e < 0.03).mean()])

    rng = np.random.default_rng(seed)
    boot = np.array(
        [
            stats([per_demo[i] for i in rng.integers(len(per_demo), size=len(per_demo))])
            for _ in range(draws)
        ]
    )
    low, high = np.percentile(boot, [2.5, 97.5], axis=0)
    names = ("mean", "median", "within_3cm")
    return {
        **{n: float(v) for n, v in zip(names, stats(per_demo), strict=True)},
        **{f"{n}_95": [float(lo), float(hi)] for n, lo, hi in zip(names, low, high, strict=True)},
        "n": int(sum(len(e) for e in per_demo)),
        "demonstrations": len(per_demo),
    }


def main(cfg: Config) -> dict:
    extra = torch.load(cfg.localizer, weights_only=True)["extra"]
    result = {
        "localizer": str(cfg.localizer),
        "trained_with": extra["train_config"],
        "train_log": extra["log"],
        "every": cfg.every,
        "novel_demo_xy_error_cm": {
            name: summary(per_demo, cfg.seed)
            for name, per_demo in locate_demonstrations(cfg).items()
        },
    }
    print(json.dumps(result["novel_demo_xy_error_cm"], indent=2))
    if cfg.out:
        cfg.out.parent.mkdir(parents=True, exist_ok=True)
        cfg.out.write_text(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    main(tyro.cli(Config))

"""How far off is the scene encoder's idea of where things are, in scenes it never saw?

Reads a trained scene encoder (`aed train-encoder`) and collections, and prints the mean error
of each predicted position (cm: the TCP, the stage target, each task object) and joint, beside
the error of always guessing the training mean (what a head that learned nothing scores):

    python scripts/localization_probe.py --encoder runs/PressButton/encoder/encoder.pt \
        --data runs/PressButton/data/base --envs 23 24 25 26 --data runs/PressButton/data/novel
    python scripts/localization_probe.py ... --roles agent_success demo --every 1000  # frame 0
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import torch
import tyro

from aed_models.data import load_episodes
from aed_models.encoder import load_encoder
from aed_models.train.encoder import localization_errors

logger = logging.getLogger("localization_probe")


@dataclass
class Config:
    encoder: Path = Path("runs/PressButton/encoder/encoder.pt")
    """The trained scene encoder."""
    data: list[Path] = field(default_factory=lambda: [Path("runs/PressButton/data/novel")])
    """Collections to measure on (base and novel alike)."""
    envs: tuple[int, ...] = ()
    """Only these environment indices of base collections (default: every one)."""
    roles: tuple[str, ...] = ()
    """Only episodes of these roles (e.g. explore: the arm anywhere; default: every one)."""
    every: int = 4
    """Every n-th frame of each episode (one longer than the episodes: the first frame alone,
    where the arm has not moved toward anything yet)."""
    out: Path | None = None
    """Also write the table as JSON here."""


def main(cfg: Config) -> dict[str, dict[str, float]]:
    encoder = load_encoder(cfg.encoder)
    trained = set(torch.load(cfg.encoder, weights_only=True)["extra"].get("train_envs", []))
    table = {}
    for root in cfg.data:
        episodes = load_episodes(root, split=None)
        if cfg.envs:
            episodes = [e for e in episodes if e.split != "base" or e.env_index in cfg.envs]
        if cfg.roles:
            episodes = [e for e in episodes if e.role in cfg.roles]
        seen = sorted({e.env_index for e in episodes if e.split == "base"} & trained)
        if seen:
            logger.warning("%s: environments %s are ones the encoder trained on", root, seen)
        errors = localization_errors(encoder, episodes, cfg.every)
        guess = localization_errors(encoder, episodes, cfg.every, mean_guess=True)
        table[str(root)] = {"episodes": len(episodes), "errors": errors, "mean_guess": guess}
        print(f"{root}: {len(episodes)} episodes")
        for name, error in errors.items():
            print(f"  {name:>14}: {error:6.2f} (mean guess {guess[name]:6.2f})")
    if cfg.out:
        cfg.out.write_text(json.dumps(table, indent=1))
    return table


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    main(tyro.cli(Config))

"""`aed train-policy` and `aed train-detector`: phases 1 and 2 of the protocol.

Thin command-line faces of the training loops in `aed_models.train`; the loops themselves
(CleanRL style, checkpointed every epoch, resumable) live beside the models.
"""

from __future__ import annotations

import time
from typing import Annotated

import tyro

from aed_models.train.detector import TrainDetectorConfig
from aed_models.train.policy import TrainPolicyConfig


def train_policy(cfg: Annotated[TrainPolicyConfig, tyro.conf.arg(name="")]) -> int:
    """Train a few-shot imitation policy on base demonstrations and agent successes (resumable)."""
    from aed_models.train.policy import train_policy as run

    start = time.perf_counter()
    path = run(cfg)
    print(f"{path}: {cfg.policy} trained on {cfg.task} ({cfg.profile}) in {time.perf_counter() - start:.0f} s")
    return 0


def train_detector(cfg: Annotated[TrainDetectorConfig, tyro.conf.arg(name="")]) -> int:
    """Train an error detector on base successes, failures and demonstrations (resumable)."""
    from aed_models.train.detector import train_detector as run

    start = time.perf_counter()
    path = run(cfg)
    print(f"{path}: {cfg.detector} trained on {cfg.task} ({cfg.profile}) in {time.perf_counter() - start:.0f} s")
    return 0

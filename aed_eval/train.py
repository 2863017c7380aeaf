"""`aed train-encoder`, `aed train-localizer`, `aed train-policy` and `aed train-detector`:
phases 1 and 2 of the protocol (under mini, the scene encoder and the target localizer first:
the policies' frozen visual head and where their targets are).

Thin command-line faces of the training loops in `aed_models.train`; the loops themselves
(CleanRL style, checkpointed every epoch, resumable) live beside the models.
"""

from __future__ import annotations

import time
from typing import Annotated, Any

import tyro

from aed_eval.checks import task_class
from aed_eval.presets import protocol
from aed_models.train.detector import TrainDetectorConfig
from aed_models.train.encoder import TrainEncoderConfig
from aed_models.train.localizer import TrainLocalizerConfig
from aed_models.train.policy import TrainPolicyConfig


def training_envs(task: str, profile: str) -> int:
    """How many base environments the protocol trains on (the rest of a collection calibrates)."""
    return protocol(profile).training_envs(task_class(task).catalogue_sizes["base"])


def encoder_preset(
    task: str = "PressButton", profile: str = "mini", **kw: Any
) -> TrainEncoderConfig:
    """`aed train-encoder`'s defaults: the encoder's recipe, on the protocol's training
    environments."""
    return TrainEncoderConfig.from_preset(
        task, profile, num_envs=training_envs(task, profile), **kw
    )


def localizer_preset(
    task: str = "PressButton", profile: str = "mini", **kw: Any
) -> TrainLocalizerConfig:
    """`aed train-localizer`'s defaults: the localizer's recipe, on the protocol's training
    environments."""
    return TrainLocalizerConfig.from_preset(
        task, profile, num_envs=training_envs(task, profile), **kw
    )


def policy_preset(
    task: str = "PressButton", policy: str = "naive_dc", profile: str = "mini", **kw: Any
) -> TrainPolicyConfig:
    """`aed train-policy`'s defaults: the policy's recipe, on the protocol's training
    environments."""
    return TrainPolicyConfig.from_preset(
        task, policy, profile, num_envs=training_envs(task, profile), **kw
    )


def detector_preset(
    task: str = "PressButton",
    detector: str = "probe",
    profile: str = "mini",
    policy: str | None = None,
    **kw: Any,
) -> TrainDetectorConfig:
    """`aed train-detector`'s defaults: the detector's recipe, on the protocol's training
    environments (PrObe and rnd_oe read naive_dc's features unless `--policy` names another)."""
    from aed_models.detectors import requires_policy

    policy = policy or ("naive_dc" if requires_policy(detector) else None)
    return TrainDetectorConfig.from_preset(
        task, detector, profile, policy=policy, num_envs=training_envs(task, profile), **kw
    )


def train_policy(cfg: Annotated[TrainPolicyConfig, tyro.conf.arg(name="")]) -> int:
    """Train a few-shot imitation policy on base demonstrations and agent successes (resumable)."""
    from aed_models.train.policy import train_policy as run

    start = time.perf_counter()
    path = run(cfg)
    print(
        f"{path}: {cfg.policy} trained on {cfg.task} ({cfg.profile}) in "
        f"{time.perf_counter() - start:.0f} s"
    )
    return 0


def train_detector(cfg: Annotated[TrainDetectorConfig, tyro.conf.arg(name="")]) -> int:
    """Train an error detector on base successes, failures and demonstrations (resumable)."""
    from aed_models.train.detector import train_detector as run

    start = time.perf_counter()
    path = run(cfg)
    print(
        f"{path}: {cfg.detector} trained on {cfg.task} ({cfg.profile}) in "
        f"{time.perf_counter() - start:.0f} s"
    )
    return 0


def train_encoder(cfg: Annotated[TrainEncoderConfig, tyro.conf.arg(name="")]) -> int:
    """Train the scene encoder (the mini policies' frozen visual head) to say where the TCP, the
    stage target and the task objects are, from single frames of the base collection
    (resumable)."""
    from aed_models.train.encoder import train_encoder as run

    start = time.perf_counter()
    path = run(cfg)
    seconds = time.perf_counter() - start
    print(f"{path}: scene encoder of {cfg.task} ({cfg.profile}) in {seconds:.0f} s")
    return 0


def train_localizer(cfg: Annotated[TrainLocalizerConfig, tyro.conf.arg(name="")]) -> int:
    """Train the target localizer (what the mini policies read of where their targets are): a
    matching map that finds, in a frame, where the demonstrations' stages ended (resumable)."""
    from aed_models.train.localizer import train_localizer as run

    start = time.perf_counter()
    path = run(cfg)
    seconds = time.perf_counter() - start
    print(f"{path}: target localizer of {cfg.task} ({cfg.profile}) in {seconds:.0f} s")
    return 0

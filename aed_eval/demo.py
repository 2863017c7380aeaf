"""`aed demo`: the whole AED protocol for one task, small enough for a 2-core CPU.

Stages: collect the base split (training and held-out calibration environments); train the
scene encoder and the target localizer when the policies read them, the policies, then the
detectors; collect the novel
split's demonstrations and labelled expert episodes; roll every policy out in the novel and
calibration environments; calibrate, evaluate, report. Each stage resumes what an earlier run
finished. Every stage is built from one named preset (`--profile`, default `demo`), so that
`aed train-policy --profile demo` trains what the demo trains.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from aed_eval.checks import check_detectors, task_class
from aed_eval.presets import Protocol, protocol
from aed_eval.scoring import DETECTOR_NAMES
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile

logger = logging.getLogger(__name__)


@dataclass
class DemoConfig(Protocol):
    """What `aed demo` runs (build it with `from_preset`): the protocol's counts and where.

    Args:
        task: task of the pipeline.
        profile: the preset of every stage: demo (CPU, minutes), mini, paper (a GPU's job).
        runs: root of everything the demo writes (the runs/ layout of aed_models.layout).
        horizon: steps of every rollout (the task's evaluation horizon by default).
        detectors: detectors trained, calibrated and evaluated.
        encoder_epochs: override the scene encoder's training epochs (0: its recipe).
        localizer_epochs: override the target localizer's training epochs (0: its recipe).
        policy_epochs: override every policy's training epochs (0: each one's recipe).
        detector_epochs: override every detector's training epochs (0: each one's recipe).
        alphas: false-alarm rates of the calibrated thresholds.
        workers: simulation processes for collection and rollouts.
        seed: root seed of every stage.
    """

    task: str
    profile: Profile
    runs: Path
    horizon: int
    detectors: tuple[str, ...] = DETECTOR_NAMES
    encoder_epochs: int = 0
    localizer_epochs: int = 0
    policy_epochs: int = 0
    detector_epochs: int = 0
    alphas: tuple[float, ...] = (0.1, 0.2)
    workers: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        from aed_models.policies import POLICIES

        task_cls = task_class(self.task)
        self.task = task_cls.task_name
        check_profile(self.profile)
        unknown = [p for p in self.policies if p not in POLICIES]
        if unknown or not self.policies:
            raise ValueError(f"policies={self.policies}: known {sorted(POLICIES)}")
        check_detectors(self.detectors)
        sizes = task_cls.catalogue_sizes
        for name in (
            "train_envs",
            "calibration_envs",
            "novel_envs",
            "num_demos",
            "num_successes",
            "num_failures",
            "rollouts",
            "calibration_rollouts",
            "workers",
            "horizon",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        for name in (
            "encoder_epochs",
            "localizer_epochs",
            "policy_epochs",
            "detector_epochs",
            "num_explore",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 0")
        if self.train_envs + self.calibration_envs > sizes["base"]:
            raise ValueError(
                f"train_envs={self.train_envs} + calibration_envs={self.calibration_envs}: "
                f"{self.task} has {sizes['base']} base environments"
            )
        if self.novel_envs > sizes["novel"]:
            raise ValueError(
                f"novel_envs={self.novel_envs}: {self.task} has {sizes['novel']} novel environments"
            )
        if not self.alphas or not all(0.0 < a < 1.0 for a in self.alphas):
            raise ValueError(f"alphas={self.alphas}: each must lie in (0, 1)")
        self.runs = Path(self.runs)

    @classmethod
    def from_preset(
        cls,
        task: str = "PressButton",
        profile: str = "demo",
        runs: Path = Path("runs/demo"),
        **overrides: Any,
    ) -> DemoConfig:
        """The profile's protocol counts and the task's evaluation horizon, then `overrides`."""
        counts, task_cls = protocol(profile), task_class(task)
        sizes = task_cls.catalogue_sizes
        preset = {
            **dataclasses.asdict(counts),
            "task": task_cls.task_name,
            "profile": profile,
            "runs": runs,
            "train_envs": counts.training_envs(sizes["base"]),
            "novel_envs": counts.rollout_envs(sizes["novel"]),
            "horizon": task_cls.eval_horizon,
        }
        return cls(**{**preset, **overrides})

    @property
    def calibration_env_indices(self) -> tuple[int, ...]:
        return tuple(range(self.train_envs, self.train_envs + self.calibration_envs))


@dataclass
class Stage:
    """One stage of the demo: its name and its jobs, each a function and the config it runs."""

    name: str
    jobs: list[tuple[Callable[[Any], Any], Any]]


def collection(c: DemoConfig, split: str, **fields: Any) -> Any:
    """A collection of the demo's `split`: its task, profile, runs, workers and seed."""
    from aed_eval.collect import CollectConfig

    return CollectConfig.from_preset(
        task=c.task,
        split=split,
        profile=c.profile,
        runs=c.runs,
        workers=c.workers,
        seed=c.seed,
        shard_size=5,
        **fields,
    )


def base_collections(c: DemoConfig) -> list[Any]:
    """The training environments (with injected failures and exploration episodes), then the
    calibration ones."""
    counts = {"num_demos": c.num_demos, "num_successes": c.num_successes}
    training = {"num_failures": c.num_failures, "num_explore": c.num_explore}
    return [
        collection(c, "base", envs=tuple(range(c.train_envs)), **training, **counts),
        collection(
            c, "base", envs=c.calibration_env_indices, num_failures=0, num_explore=0, **counts
        ),
    ]


def encoder_trainings(c: DemoConfig) -> list[Any]:
    """The scene encoder, when a policy of the demo reads it frozen."""
    from aed_models.policies import POLICIES
    from aed_models.train.encoder import TrainEncoderConfig

    if not any(POLICIES.preset(p, c.profile).frozen_encoder for p in c.policies):
        return []
    epochs = {"epochs": c.encoder_epochs} if c.encoder_epochs else {}
    return [
        TrainEncoderConfig.from_preset(
            c.task, c.profile, runs=c.runs, num_envs=c.train_envs, seed=c.seed, **epochs
        )
    ]


def localizer_trainings(c: DemoConfig) -> list[Any]:
    """The target localizer, when a policy of the demo reads it."""
    from aed_models.policies import POLICIES
    from aed_models.train.localizer import TrainLocalizerConfig

    if not any(POLICIES.preset(p, c.profile).localizer is not None for p in c.policies):
        return []
    epochs = {"epochs": c.localizer_epochs} if c.localizer_epochs else {}
    return [
        TrainLocalizerConfig.from_preset(
            c.task, c.profile, runs=c.runs, num_envs=c.train_envs, seed=c.seed, **epochs
        )
    ]


def policy_trainings(c: DemoConfig) -> list[Any]:
    from aed_models.train.policy import TrainPolicyConfig

    epochs = {"epochs": c.policy_epochs} if c.policy_epochs else {}
    configs = []
    for policy in c.policies:
        cfg = TrainPolicyConfig.from_preset(
            c.task, policy, c.profile, runs=c.runs, num_envs=c.train_envs, seed=c.seed, **epochs
        )
        collected = (c.num_demos, c.num_successes)
        configs.append(dataclasses.replace(cfg, composition=at_most(cfg.composition, collected)))
    return configs


def detector_trainings(c: DemoConfig) -> list[Any]:
    from aed_models.detectors import requires_policy
    from aed_models.train.detector import TrainDetectorConfig

    epochs = {"epochs": c.detector_epochs} if c.detector_epochs else {}
    configs = []
    for detector in c.detectors:
        for policy in c.policies if requires_policy(detector) else (None,):
            cfg = TrainDetectorConfig.from_preset(
                c.task,
                detector,
                c.profile,
                policy=policy,
                runs=c.runs,
                num_envs=c.train_envs,
                seed=c.seed,
                **epochs,
            )
            collected = (c.num_demos, c.num_successes, c.num_failures)
            configs.append(
                dataclasses.replace(cfg, composition=at_most(cfg.composition, collected))
            )
    return configs


def novel_collections(c: DemoConfig) -> list[Any]:
    """The novel demonstrations, then the labelled expert episodes (successes and failures)."""
    envs = {"num_envs": c.novel_envs}
    configs = [
        collection(c, "novel", num_demos=c.num_demos, num_successes=0, num_failures=0, **envs)
    ]
    if c.labelled:
        out = RunLayout(c.runs).labelled(c.task, "novel")
        labelled = {"num_successes": c.labelled, "num_failures": c.labelled}
        configs.append(collection(c, "novel", num_demos=0, out=out, **labelled, **envs))
    return configs


def rollouts(c: DemoConfig) -> list[Any]:
    """Each policy in the novel environments, then in the held-out calibration ones."""
    from aed_eval.rollout import RolloutConfig

    common = {
        "task": c.task,
        "runs": c.runs,
        "profile": c.profile,
        "num_demos": c.num_demos,
        "workers": c.workers,
        "horizon": c.horizon,
        "seed": c.seed,
    }
    configs = []
    for policy in c.policies:
        configs.append(
            RolloutConfig.from_preset(
                **common,
                policy=policy,
                split="novel",
                num_envs=c.novel_envs,
                num_episodes=c.rollouts,
            )
        )
        configs.append(
            RolloutConfig.from_preset(
                **common,
                policy=policy,
                split="base",
                envs=c.calibration_env_indices,
                num_episodes=c.calibration_rollouts,
            )
        )
    return configs


def calibrations(c: DemoConfig) -> list[Any]:
    from aed_eval.calibrate import SOURCES, CalibrateConfig

    return [
        CalibrateConfig(
            task=c.task,
            policy=policy,
            detectors=c.detectors,
            alphas=c.alphas,
            source=source,
            envs=c.calibration_env_indices,
            num_demos=c.num_demos,
            runs=c.runs,
        )
        for policy in c.policies
        for source in SOURCES
    ]


def evaluations(c: DemoConfig) -> list[Any]:
    from aed_eval.evaluate import EvaluateConfig

    labelled = RunLayout(c.runs).labelled(c.task, "novel") if c.labelled else None
    return [
        EvaluateConfig(
            task=c.task,
            policy=policy,
            detectors=c.detectors,
            num_demos=c.num_demos,
            labelled=labelled,
            runs=c.runs,
            seed=c.seed,
        )
        for policy in c.policies
    ]


def plan_stages(c: DemoConfig) -> list[Stage]:
    """Every stage's configs, built (so validated) before any work starts: a bad value is
    refused at once, with nothing written, not after the first stages ran."""
    from aed_eval.calibrate import calibrate_detectors
    from aed_eval.collect import run_collection
    from aed_eval.evaluate import evaluate_policy
    from aed_eval.rollout import run_rollouts
    from aed_models.train.detector import train_detector
    from aed_models.train.encoder import train_encoder
    from aed_models.train.localizer import train_localizer
    from aed_models.train.policy import train_policy

    stages = [
        ("collect base split", run_collection, base_collections(c)),
        ("train scene encoder", train_encoder, encoder_trainings(c)),
        ("train target localizer", train_localizer, localizer_trainings(c)),
        ("train policies", train_policy, policy_trainings(c)),
        ("train detectors", train_detector, detector_trainings(c)),
        ("collect novel split", run_collection, novel_collections(c)),
        ("roll out policies", run_rollouts, rollouts(c)),
        ("calibrate detectors", calibrate_detectors, calibrations(c)),
        ("evaluate", evaluate_policy, evaluations(c)),
    ]
    return [Stage(name, [(fn, cfg) for cfg in configs]) for name, fn, configs in stages]


def at_most(composition: tuple[int, ...], collected: tuple[int, ...]) -> tuple[int, ...]:
    """A recipe's draws per iteration, capped at what the demo collected per environment."""
    return tuple(min(want, have) for want, have in zip(composition, collected, strict=True))


def timed(times: dict[str, float], name: str, fn: Callable[[], Any]) -> Any:
    """Run `fn`, logging the stage and storing its seconds in `times[name]`."""
    logger.info("demo: %s", name)
    start = time.perf_counter()
    result = fn()
    times[name] = round(time.perf_counter() - start, 1)
    logger.info("demo: %s done in %.0f s", name, times[name])
    return result


def run_demo(cfg: DemoConfig) -> tuple[Path, dict[str, float]]:
    """Every stage in order (all planned first); returns the report's path and the stage times."""
    from aed_eval.report import ReportConfig, make_report

    stages, times = plan_stages(cfg), {}
    for stage in stages:
        timed(times, stage.name, lambda jobs=stage.jobs: [fn(job) for fn, job in jobs])
    results = tuple(Path(job.out) / "results.json" for _, job in stages[-1].jobs)
    report = ReportConfig(results=results, out=RunLayout(cfg.runs).report())
    return timed(times, "report", lambda: make_report(report)), times


def demo(cfg: Annotated[DemoConfig, tyro.conf.arg(name="")]) -> int:
    """The whole AED pipeline for one task on this CPU: collect, train, roll out, calibrate,
    evaluate, report."""
    from aed_eval.doctor import rendering_device

    if rendering_device() is None:
        logger.error("SAPIEN finds no rendering device: run `aed doctor`")
        return 1
    start = time.perf_counter()
    path, times = run_demo(cfg)
    total = time.perf_counter() - start
    summary = {
        "config": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(cfg).items()},
        "stage_seconds": times,
        "total_seconds": round(total, 1),
        "report": str(path),
    }
    (cfg.runs / "demo.json").write_text(json.dumps(summary, indent=2))
    print(path.read_text())
    print(
        f"ran: {cfg.task}, policies {', '.join(cfg.policies)}, detectors "
        f"{', '.join(cfg.detectors)}; trained on {cfg.train_envs} base environments, calibrated on "
        f"{cfg.calibration_envs} held-out ones x {cfg.calibration_rollouts} rollouts, deployed in "
        f"{cfg.novel_envs} novel environments x {cfg.rollouts} rollouts of {cfg.horizon} steps"
    )
    print("stage times: " + ", ".join(f"{k} {v:.0f} s" for k, v in times.items()))
    print(f"demo finished in {total / 60:.1f} min; report: {path}")
    return 0

"""`aed demo`: the whole AED protocol for one task, small enough for a 2-core CPU.

Stages: collect the base split (training and held-out calibration environments); train the
scene encoder when the policies read it, the policies, then the detectors; collect the novel
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
        for name in ("encoder_epochs", "policy_epochs", "detector_epochs"):
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
            "novel_envs": counts.novel_envs or sizes["novel"],
            "horizon": task_cls.eval_horizon,
        }
        return cls(**{**preset, **overrides})

    @property
    def calibration_env_indices(self) -> tuple[int, ...]:
        return tuple(range(self.train_envs, self.train_envs + self.calibration_envs))


class Stages:
    """Runs the stages in order, timing each (seconds in `times`)."""

    def __init__(self, cfg: DemoConfig):
        self.cfg = cfg
        self.layout = RunLayout(cfg.runs)
        self.times: dict[str, float] = {}

    def timed(self, name: str, fn: Any, *args: Any) -> Any:
        logger.info("demo: %s", name)
        start = time.perf_counter()
        result = fn(*args)
        self.times[name] = round(time.perf_counter() - start, 1)
        logger.info("demo: %s done in %.0f s", name, self.times[name])
        return result

    def collect_base(self) -> None:
        from aed_eval.collect import CollectConfig, run_collection

        c = self.cfg
        common = {
            "task": c.task,
            "split": "base",
            "profile": c.profile,
            "runs": c.runs,
            "num_demos": c.num_demos,
            "num_successes": c.num_successes,
            "workers": c.workers,
            "seed": c.seed,
            "shard_size": 5,
        }
        run_collection(
            CollectConfig.from_preset(
                **common, envs=tuple(range(c.train_envs)), num_failures=c.num_failures
            )
        )
        run_collection(
            CollectConfig.from_preset(**common, envs=c.calibration_env_indices, num_failures=0)
        )

    def train_encoder(self) -> None:
        from aed_models.policies import POLICIES
        from aed_models.train.encoder import TrainEncoderConfig, train_encoder

        c = self.cfg
        if any(POLICIES.preset(p, c.profile).frozen_encoder for p in c.policies):
            epochs = {"epochs": c.encoder_epochs} if c.encoder_epochs else {}
            train_encoder(
                TrainEncoderConfig.from_preset(
                    c.task, c.profile, runs=c.runs, num_envs=c.train_envs, seed=c.seed, **epochs
                )
            )

    def train_policies(self) -> None:
        from aed_models.train.policy import TrainPolicyConfig, train_policy

        c = self.cfg
        epochs = {"epochs": c.policy_epochs} if c.policy_epochs else {}
        for policy in c.policies:
            cfg = TrainPolicyConfig.from_preset(
                c.task, policy, c.profile, runs=c.runs, num_envs=c.train_envs, seed=c.seed, **epochs
            )
            collected = (c.num_demos, c.num_successes)
            train_policy(dataclasses.replace(cfg, composition=at_most(cfg.composition, collected)))

    def train_detectors(self) -> None:
        from aed_models.detectors import requires_policy
        from aed_models.train.detector import TrainDetectorConfig, train_detector

        c = self.cfg
        epochs = {"epochs": c.detector_epochs} if c.detector_epochs else {}
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
                train_detector(
                    dataclasses.replace(cfg, composition=at_most(cfg.composition, collected))
                )

    def collect_novel(self) -> None:
        from aed_eval.collect import CollectConfig, run_collection

        c = self.cfg
        common = {
            "task": c.task,
            "split": "novel",
            "profile": c.profile,
            "runs": c.runs,
            "num_envs": c.novel_envs,
            "workers": c.workers,
            "seed": c.seed,
            "shard_size": 5,
        }
        run_collection(
            CollectConfig.from_preset(
                **common, num_demos=c.num_demos, num_successes=0, num_failures=0
            )
        )
        if c.labelled:
            run_collection(
                CollectConfig.from_preset(
                    **common,
                    num_demos=0,
                    num_successes=c.labelled,
                    num_failures=c.labelled,
                    out=self.layout.labelled(c.task, "novel"),
                )
            )

    def roll_out(self) -> None:
        from aed_eval.rollout import RolloutConfig, run_rollouts

        c = self.cfg
        common = {
            "task": c.task,
            "runs": c.runs,
            "profile": c.profile,
            "num_demos": c.num_demos,
            "workers": c.workers,
            "horizon": c.horizon,
            "seed": c.seed,
        }
        for policy in c.policies:
            run_rollouts(
                RolloutConfig.from_preset(
                    **common,
                    policy=policy,
                    split="novel",
                    num_envs=c.novel_envs,
                    num_episodes=c.rollouts,
                )
            )
            run_rollouts(
                RolloutConfig.from_preset(
                    **common,
                    policy=policy,
                    split="base",
                    envs=c.calibration_env_indices,
                    num_episodes=c.calibration_rollouts,
                )
            )

    def calibrate(self) -> None:
        from aed_eval.calibrate import SOURCES, CalibrateConfig, calibrate_detectors

        c = self.cfg
        for policy in c.policies:
            for source in SOURCES:
                calibrate_detectors(
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
                )

    def evaluate(self) -> list[Path]:
        from aed_eval.evaluate import EvaluateConfig, evaluate_policy

        c = self.cfg
        paths = []
        for policy in c.policies:
            cfg = EvaluateConfig(
                task=c.task,
                policy=policy,
                detectors=c.detectors,
                num_demos=c.num_demos,
                runs=c.runs,
                seed=c.seed,
            )
            evaluate_policy(cfg)
            paths.append(Path(cfg.out) / "results.json")
        return paths

    def report(self, results: list[Path]) -> Path:
        from aed_eval.report import ReportConfig, make_report

        return make_report(ReportConfig(results=tuple(results), out=self.layout.report()))


def at_most(composition: tuple[int, ...], collected: tuple[int, ...]) -> tuple[int, ...]:
    """A recipe's draws per iteration, capped at what the demo collected per environment."""
    return tuple(min(want, have) for want, have in zip(composition, collected, strict=True))


def run_demo(cfg: DemoConfig) -> tuple[Path, dict[str, float]]:
    """Every stage in order; returns the report's path and the stage times."""
    stages = Stages(cfg)
    stages.timed("collect base split", stages.collect_base)
    stages.timed("train scene encoder", stages.train_encoder)
    stages.timed("train policies", stages.train_policies)
    stages.timed("train detectors", stages.train_detectors)
    stages.timed("collect novel split", stages.collect_novel)
    stages.timed("roll out policies", stages.roll_out)
    stages.timed("calibrate detectors", stages.calibrate)
    results = stages.timed("evaluate", stages.evaluate)
    path = stages.timed("report", stages.report, results)
    return path, stages.times


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

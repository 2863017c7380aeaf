"""`aed demo`: the whole AED protocol for one task, small enough for a 2-core CPU.

Stages, each reusing what an earlier run finished (collections and rollouts resume shard by
shard, training resumes from its last epoch):

1. collect the base split (`aed collect`): demonstrations, agent successes and labelled agent
   failures in the training environments; demonstrations and a few expert successes in the
   held-out calibration environments, which no model trains on;
2. phase 1: train the policies (`aed train-policy`) on the training environments;
3. phase 2: train the detectors (`aed train-detector`; PrObe and rnd_oe once per policy);
4. collect the novel split: the environments' demonstrations, and labelled expert episodes
   (successes and injected failures) for the delay metrics;
5. phase 3: roll every policy out in the novel environments, and in the calibration
   environments (`aed rollout`; every rollout runs the task's horizon);
6. calibrate every detector's thresholds on the policy's successful calibration rollouts, and
   on the expert's successes there for comparison (`aed calibrate`);
7. score the rollouts and compute the metrics (`aed evaluate`), then the report (`aed report`).

Under `--profile mini` (the default) the models have the `mini` sizes but the counts are the
demo's, smaller than `aed train-policy --profile mini` uses (sized so that the policies
learn): the demo shows the pipeline end to end in minutes, and its numbers are those of
briefly trained models. `--profile paper` runs the same stages at the paper's sizes.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from aed_eval.checks import check_detectors, task_class
from aed_eval.layout import RunLayout
from aed_eval.scoring import DETECTOR_NAMES

logger = logging.getLogger(__name__)


# Per profile. `mini` is the demo's CPU default, sized to finish in about 20 minutes on two
# cores: one policy (DCT), every detector, small CNN heads, a few environments, briefly trained
# models, and every rollout the task's horizon long. `paper` is the paper's protocol at its
# sizes (ResNet18 heads, every base environment but the calibration ones, 5 demos / 20
# successes / 20 failures, 20 rollouts per novel environment, the paper's epochs): a GPU
# machine's job.
PROFILES: dict[str, dict[str, Any]] = {
    "mini": {"policies": ("dct",), "train_envs": 5, "calibration_envs": 3, "novel_envs": 6, "num_demos": 3,
             "num_successes": 4, "num_failures": 3, "labelled": 1, "rollouts": 4, "calibration_rollouts": 4,
             "policy_epochs": 20, "detector_epochs": 4},
    "paper": {"policies": ("naive_dc", "dct", "scan"), "train_envs": None, "calibration_envs": 4, "novel_envs": None,
              "num_demos": 5, "num_successes": 20, "num_failures": 20, "labelled": 5, "rollouts": 20,
              "calibration_rollouts": 20, "policy_epochs": None, "detector_epochs": None},
}  # fmt: skip


@dataclass
class DemoConfig:
    """What `aed demo` runs (counts are per environment; unset ones take the profile's)."""

    task: str = "PressButton"
    """Task of the pipeline."""
    profile: Literal["mini", "paper"] = "mini"
    """mini: CPU-sized models and counts (minutes); paper: the paper's sizes (for a GPU machine)."""
    policies: tuple[str, ...] | None = None
    """Policies trained and rolled out (mini: dct; paper: naive_dc, dct, scan)."""
    detectors: tuple[str, ...] = DETECTOR_NAMES
    """Detectors trained, calibrated and evaluated."""
    runs: Path = Path("runs/demo")
    """Root of everything the demo writes (the runs/ layout of aed_eval.layout)."""
    train_envs: int | None = None
    """Base environments the models train on (paper: all but the calibration ones)."""
    calibration_envs: int | None = None
    """Further base environments, held out of all training, for calibration."""
    novel_envs: int | None = None
    """Novel environments the policies are deployed in (paper: all)."""
    num_demos: int | None = None
    """Demonstrations per environment."""
    num_successes: int | None = None
    """Agent successes per base environment (calibration environments: for the expert calibration)."""
    num_failures: int | None = None
    """Agent failures per training environment."""
    labelled: int | None = None
    """Labelled expert successes and failures (each) per novel environment."""
    rollouts: int | None = None
    """Policy rollouts per novel environment."""
    calibration_rollouts: int | None = None
    """Policy rollouts per calibration environment (their successes calibrate the thresholds)."""
    policy_epochs: int | None = None
    """Policy training epochs (paper: the paper's per task)."""
    detector_epochs: int | None = None
    """Detector training epochs (paper: the paper's per task)."""
    horizon: int | None = None
    """Steps of every rollout (default: the task's evaluation horizon)."""
    alphas: tuple[float, ...] = (0.1, 0.2)
    """False-alarm rates of the calibrated thresholds."""
    workers: int = 2
    """Simulation processes for collection and rollouts."""
    seed: int = 0
    """Root seed of every stage."""

    def __post_init__(self) -> None:
        task_cls = task_class(self.task)
        self.task = task_cls.task_name
        if self.profile not in PROFILES:
            raise ValueError(f"profile={self.profile!r}: known {sorted(PROFILES)}")
        for name, value in PROFILES[self.profile].items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        from aed_models.policies import POLICIES

        unknown = [p for p in self.policies if p not in POLICIES]
        if unknown or not self.policies:
            raise ValueError(f"policies={self.policies}: known {sorted(POLICIES)}")
        check_detectors(self.detectors)
        sizes = task_cls.catalogue_sizes
        if self.train_envs is None:
            self.train_envs = sizes["base"] - self.calibration_envs
        if self.novel_envs is None:
            self.novel_envs = sizes["novel"]
        for name in ("train_envs", "calibration_envs", "novel_envs", "num_demos", "num_successes", "num_failures",
                     "rollouts", "calibration_rollouts", "workers"):  # fmt: skip
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)}: must be >= 1")
        if self.train_envs + self.calibration_envs > sizes["base"]:
            raise ValueError(f"train_envs={self.train_envs} + calibration_envs={self.calibration_envs}: "
                             f"{self.task} has {sizes['base']} base environments")  # fmt: skip
        if self.novel_envs > sizes["novel"]:
            raise ValueError(f"novel_envs={self.novel_envs}: {self.task} has {sizes['novel']} novel environments")
        if not self.alphas or not all(0.0 < a < 1.0 for a in self.alphas):
            raise ValueError(f"alphas={self.alphas}: each must lie in (0, 1)")
        self.runs = Path(self.runs)

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

    def composition(self) -> tuple[int, int, int] | None:
        """Under `mini`, a detector's iteration draws what was collected (demos, successes,
        failures) instead of the paper's 5 / 10 / 10 with replacement: the same information at a
        third of the cost. (Policies draw the mini profile's successes, at most those collected.)"""
        c = self.cfg
        return (c.num_demos, c.num_successes, c.num_failures) if c.profile == "mini" else None

    def collect_base(self) -> None:
        from aed_eval.collect import CollectConfig, run_collection

        c = self.cfg
        common = {"task": c.task, "split": "base", "num_demos": c.num_demos, "num_successes": c.num_successes,
                  "workers": c.workers, "seed": c.seed, "out": self.layout.data(c.task, "base"), "profile": c.profile,
                  "shard_size": 5}  # fmt: skip
        run_collection(CollectConfig(**common, envs=tuple(range(c.train_envs)), num_failures=c.num_failures))
        run_collection(CollectConfig(**common, envs=c.calibration_env_indices, num_failures=0))

    def train_policies(self) -> None:
        from aed_models.train.policy import MINI, MINI_COMPOSITION, TrainPolicyConfig, train_policy

        c = self.cfg
        for policy in c.policies:
            successes = min(MINI_COMPOSITION.get(policy, MINI["composition"])[1], c.num_successes)
            train_policy(TrainPolicyConfig(
                task=c.task, policy=policy, profile=c.profile, data=self.layout.data(c.task, "base"),
                out=self.layout.policy(c.task, policy).parent, epochs=c.policy_epochs, num_envs=c.train_envs,
                seed=c.seed, composition=None if c.profile == "paper" else (c.num_demos, successes),
            ))  # fmt: skip

    def train_detectors(self) -> None:
        from aed_models.detectors import DETECTORS
        from aed_models.train.detector import TrainDetectorConfig, train_detector

        c = self.cfg
        for detector in c.detectors:
            per_policy = DETECTORS[detector].model_type().requires_policy
            for policy in c.policies if per_policy else c.policies[:1]:
                train_detector(TrainDetectorConfig(
                    task=c.task, detector=detector, policy=str(self.layout.policy(c.task, policy)) if per_policy else None,
                    profile=c.profile, data=self.layout.data(c.task, "base"), epochs=c.detector_epochs,
                    out=self.layout.detector(c.task, detector, policy).parent, num_envs=c.train_envs, seed=c.seed,
                    composition=self.composition(),
                ))  # fmt: skip

    def collect_novel(self) -> None:
        from aed_eval.collect import CollectConfig, run_collection

        c = self.cfg
        common = {"task": c.task, "split": "novel", "num_envs": c.novel_envs, "workers": c.workers, "seed": c.seed,
                  "profile": c.profile, "shard_size": 5}  # fmt: skip
        run_collection(CollectConfig(**common, num_demos=c.num_demos, num_successes=0, num_failures=0,
                                     out=self.layout.data(c.task, "novel")))  # fmt: skip
        if c.labelled:
            run_collection(CollectConfig(**common, num_demos=0, num_successes=c.labelled, num_failures=c.labelled,
                                         out=self.layout.labelled(c.task, "novel")))  # fmt: skip

    def roll_out(self) -> None:
        from aed_eval.rollout import RolloutConfig, run_rollouts

        c = self.cfg
        common = {"task": c.task, "runs": c.runs, "profile": c.profile, "num_demos": c.num_demos, "workers": c.workers,
                  "horizon": c.horizon, "seed": c.seed}  # fmt: skip
        for policy in c.policies:
            run_rollouts(RolloutConfig(**common, policy=policy, split="novel", num_envs=c.novel_envs,
                                       num_episodes=c.rollouts))  # fmt: skip
            run_rollouts(RolloutConfig(**common, policy=policy, split="base", envs=c.calibration_env_indices,
                                       num_episodes=c.calibration_rollouts))  # fmt: skip

    def calibrate(self) -> None:
        from aed_eval.calibrate import SOURCES, CalibrateConfig, calibrate_detectors

        c = self.cfg
        for policy in c.policies:
            for source in SOURCES:
                calibrate_detectors(CalibrateConfig(task=c.task, policy=policy, detectors=c.detectors, alphas=c.alphas,
                                                    source=source, envs=c.calibration_env_indices,
                                                    num_demos=c.num_demos, runs=c.runs))  # fmt: skip

    def evaluate(self) -> list[Path]:
        from aed_eval.evaluate import EvaluateConfig, evaluate_policy

        c = self.cfg
        paths = []
        for policy in c.policies:
            cfg = EvaluateConfig(task=c.task, policy=policy, detectors=c.detectors, num_demos=c.num_demos, runs=c.runs,
                                 seed=c.seed)  # fmt: skip
            evaluate_policy(cfg)
            paths.append(Path(cfg.out) / "results.json")
        return paths

    def report(self, results: list[Path]) -> Path:
        from aed_eval.report import ReportConfig, make_report

        return make_report(ReportConfig(results=tuple(results), out=self.layout.report()))


def run_demo(cfg: DemoConfig) -> tuple[Path, dict[str, float]]:
    """Every stage in order; returns the report's path and the stage times."""
    stages = Stages(cfg)
    stages.timed("collect base split", stages.collect_base)
    stages.timed("train policies", stages.train_policies)
    stages.timed("train detectors", stages.train_detectors)
    stages.timed("collect novel split", stages.collect_novel)
    stages.timed("roll out policies", stages.roll_out)
    stages.timed("calibrate detectors", stages.calibrate)
    results = stages.timed("evaluate", stages.evaluate)
    path = stages.timed("report", stages.report, results)
    return path, stages.times


def demo(cfg: Annotated[DemoConfig, tyro.conf.arg(name="")]) -> int:
    """The whole AED pipeline for one task on this CPU: collect, train, roll out, calibrate, evaluate, report."""
    from aed_eval.doctor import rendering_device

    if rendering_device() is None:
        logger.error("SAPIEN finds no rendering device: run `aed doctor`")
        return 1
    start = time.perf_counter()
    path, times = run_demo(cfg)
    total = time.perf_counter() - start
    summary = {"config": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(cfg).items()},
               "stage_seconds": times, "total_seconds": round(total, 1), "report": str(path)}  # fmt: skip
    (cfg.runs / "demo.json").write_text(json.dumps(summary, indent=2))
    print(path.read_text())
    print(f"ran: {cfg.task}, policies {', '.join(cfg.policies)}, detectors {', '.join(cfg.detectors)}; trained on "
          f"{cfg.train_envs} base environments, calibrated on {cfg.calibration_envs} held-out ones x "
          f"{cfg.calibration_rollouts} rollouts, deployed in {cfg.novel_envs} novel environments x {cfg.rollouts} "
          f"rollouts of {cfg.horizon or task_class(cfg.task).eval_horizon} steps")  # fmt: skip
    print("stage times: " + ", ".join(f"{k} {v:.0f} s" for k, v in times.items()))
    print(f"demo finished in {total / 60:.1f} min; report: {path}")
    return 0

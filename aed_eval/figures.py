"""The experiments read off the main experiment's runs: timing accuracy, the success window,
the embedding figure and the error-correction pilot.

Each is one record per (task, policy) under `results/<profile>/<name>/` (`aed_eval.results`
renders its table and figure), computed from the main run's evaluations, labelled episodes and
rollouts. `aed experiments --experiments timing_accuracy success_window embeddings
error_correction` runs them as jobs after the main stages they read; `scripts/<name>.py` runs
one by hand.
"""

from __future__ import annotations

import logging
import shlex
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from aed_eval.correction import CorrectionConfig, correction_record
from aed_eval.embeddings import EmbeddingsConfig, embeddings_record
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import PAPER_TASK_ORDER

logger = logging.getLogger(__name__)


@dataclass
class CaseConfig:
    """One (task, policy) evaluation that an experiment reads off the main runs.

    Args:
        task: task name.
        policy: the evaluated policy.
        profile: the profile of the runs.
        runs: runs folder (default runs/<profile>).
        out: folder of the record (default results/<profile>/<experiment>).
    """

    experiment: ClassVar[str]

    task: str = "PressButton"
    policy: str = "scan"
    profile: Profile = "mini"
    runs: Path | None = None
    out: Path | None = None

    def __post_init__(self) -> None:
        check_profile(self.profile)
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile
        self.out = Path(self.out or Path("results") / self.profile / self.experiment)


@dataclass
class TimingConfig(CaseConfig):
    """The timing-accuracy record of one (task, policy) evaluation.

    Args:
        calibration: which calibrated threshold: `policy` (the policy's own successes) or
            `expert`.
        alpha: the threshold's false-alarm rate.
    """

    experiment: ClassVar[str] = "timing_accuracy"

    calibration: str = "policy"
    alpha: float = 0.1


@dataclass
class SuccessWindowConfig(CaseConfig):
    """The success-window record of one (task, policy) evaluation (horizon ending)."""

    experiment: ClassVar[str] = "success_window"


def success_window_of(cfg: SuccessWindowConfig) -> dict[str, Any]:
    from aed_eval.results.success_window import success_window_record

    layout = RunLayout(cfg.runs)
    return success_window_record(
        layout.evaluation(cfg.task, cfg.policy), layout.rollouts(cfg.task, cfg.policy, "novel")
    )


def timing_accuracy_record(cfg: TimingConfig) -> dict[str, Any]:
    from aed_eval.results.timing import timing_record

    return timing_record(
        RunLayout(cfg.runs).evaluation(cfg.task, cfg.policy), cfg.calibration, cfg.alpha
    )


@dataclass(frozen=True)
class Figure:
    """One experiment read off the main runs: its default cases, its config and record."""

    name: str
    tasks: tuple[str, ...]
    policies: tuple[str, ...]
    config: Callable[..., Any]
    record: Callable[[Any], dict[str, Any]]
    script: tuple[str, ...]  # how its script names one case: (task flag, policy flag)


FIGURES = {
    f.name: f
    for f in (
        Figure(
            "timing_accuracy",
            PAPER_TASK_ORDER,
            ("naive_dc", "dct", "scan"),
            TimingConfig,
            timing_accuracy_record,
            ("--tasks", "--policies"),
        ),
        Figure(
            "success_window",
            PAPER_TASK_ORDER,
            ("naive_dc", "dct", "scan"),
            SuccessWindowConfig,
            success_window_of,
            ("--tasks", "--policies"),
        ),
        Figure(
            "embeddings",
            ("PickPlace",),
            ("scan",),
            EmbeddingsConfig,
            embeddings_record,
            ("--task", "--policy"),
        ),
        Figure(
            "error_correction",
            ("PressButton",),
            ("dct",),
            CorrectionConfig,
            correction_record,
            ("--task", "--policy"),
        ),
    )
}


@dataclass
class FigureJob:
    """One record to write: the experiment's name, the case's config, the command that
    reproduces it by hand."""

    name: str
    config: Any
    command: str


def figure_jobs(name: str, task: str, profile: str, runs: Path, results: Path) -> list[FigureJob]:
    """The jobs of experiment `name` on `task`: one per policy of its default cases."""
    f = FIGURES[name]
    jobs = []
    for policy in f.policies:
        config = f.config(
            task=task, policy=policy, profile=profile, runs=runs, out=Path(results) / name
        )
        task_flag, policy_flag = f.script
        command = shlex.join(
            ["python", f"scripts/{name}.py", "--profile", profile, "--runs", str(runs)]
            + [task_flag, task, policy_flag, policy, "--out", str(config.out)]
        )
        jobs.append(FigureJob(name, config, command))
    return jobs


def run_figure(job: FigureJob) -> list[Path]:
    """Compute the case's record and write it with its table and figure."""
    from aed_eval.results import write_result

    record = {**FIGURES[job.name].record(job.config), "command": job.command}
    return write_result(Path(job.config.out) / f"{record['task']}_{record['policy']}.json", record)


@dataclass
class CasesConfig:
    """What `scripts/<experiment>.py` reads: every (task, policy) evaluated under the runs of a
    profile."""

    profile: Profile = "mini"
    """The profile whose evaluations are read; results go to results/<profile>/."""
    runs: Path | None = None
    """Runs folder (default: runs/<profile>, where `aed experiments` writes)."""
    tasks: tuple[str, ...] = PAPER_TASK_ORDER
    policies: tuple[str, ...] = ("naive_dc", "dct", "scan")
    out: Path | None = None
    """Folder of the records (default: results/<profile>/<experiment>)."""

    def __post_init__(self) -> None:
        check_profile(self.profile)
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile


def run_evaluated_cases(name: str, cases: CasesConfig, **options: Any) -> list[Path]:
    """Experiment `name`'s record for every (task, policy) of `cases` evaluated under its runs,
    those not evaluated skipped; `options` go to the experiment's config."""
    layout = RunLayout(cases.runs)
    written = []
    for task in cases.tasks:
        for policy in cases.policies:
            folder = layout.evaluation(task, policy)
            if not (folder / "scores.json").is_file():
                logger.info("%s / %s: not evaluated (%s), skipped", task, policy, folder)
                continue
            config = FIGURES[name].config(
                task=task,
                policy=policy,
                profile=cases.profile,
                runs=cases.runs,
                out=cases.out,
                **options,
            )
            paths = run_figure(FigureJob(name, config, shlex.join(["python", *sys.argv])))
            logger.info("%s / %s: %s", task, policy, ", ".join(str(p) for p in paths))
            written += paths
    if not written:
        raise SystemExit(
            f"{cases.runs}: no evaluation of {list(cases.tasks)} x {list(cases.policies)}"
        )
    return written

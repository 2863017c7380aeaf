"""`aed experiments`: the paper's experiments, planned, resumed and reported.

The main experiment is, task by task, the protocol `aed demo` runs for one (collect, train the
scene encoder, localizer, policies and detectors, roll out, calibrate, evaluate) under the
chosen profile's counts, then one report over every task. It takes many hours on two cores, so
it is a list of jobs (one stage's config each) and a ledger, `<runs>/experiments.json`, of the
jobs that finished: a run skips every job the ledger holds with the same config and resumes
the first one that did not finish (each stage resumes its own folder). Stop it at any time, run
the same command again. `--plan` prints what is done and what is left, and runs nothing;
`--policies-only` runs what the policies' novel success rates need and leaves the detectors'
jobs (and so the cases) for a later run.

A runs folder does not outlive the machine it was written on, so the unit of progress is the
(task, policy) case: a task's jobs run case by case, and each finished case is committed as a
record under `results/<profile>/main/` with the digests of the jobs that made it. A case whose
record matches is done on any machine; only the jobs of open cases run.

The ablations, the stability runs, the demonstration-quality and viewpoint-shift experiments
(`--experiments rollout_augmentation probe_components seeds demo_quality viewpoint`,
`aed_eval.variants`) add variants on top of the main experiment's stages for their tasks (Pick &
Place and Press Button, as the paper), and write their records under `results/<profile>/`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import shlex
import sys
import time
from collections import Counter
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from aed_eval.checks import task_class
from aed_models.layout import RunLayout
from aed_models.recipe import Profile, check_profile
from aed_tasks import PAPER_TASK_ORDER, trajectory
from aed_tasks.locks import folder_lock

logger = logging.getLogger(__name__)

LEDGER = "experiments.json"

POLICY_STAGES = (
    "collect base split",
    "train scene encoder",
    "train target localizer",
    "train policies",
    "collect novel split",
    "roll out policies",
)
"""The main stages a policy's novel success rate stands on (`--policies-only`)."""

READS = {
    "train scene encoder": ("collect base split",),
    "train target localizer": ("collect base split",),
    "train policies": ("collect base split", "train scene encoder", "train target localizer"),
    "train detectors": ("collect base split", "train policies"),
    "roll out policies": ("collect novel split", "train policies"),
    "calibrate detectors": ("train detectors", "roll out policies"),
    "evaluate": (
        "collect novel split",
        "train detectors",
        "roll out policies",
        "calibrate detectors",
    ),
}
"""What each main stage reads of the stages before it (of its task: the shared jobs and its own
case's). A job is done only while what it read is: a retrained policy is rolled out again."""

ADDED_FIELDS = {"precision": "fp32"}
"""Config fields added after jobs were recorded, at the value every earlier job ran with: left
out of a job's digest at that value, so that finished jobs keep their digests."""


@dataclass
class ExperimentsConfig:
    """The main experiment's grid and where it is written.

    Args:
        profile: the preset of every stage: mini (this CPU, many hours), paper (a GPU's job),
            demo (minutes a task).
        experiments: main (every task x policy x detector), any of the variant experiments
            of `aed_eval.variants` (rollout_augmentation, probe_components, seeds,
            demo_quality, viewpoint) and of the records read off the main runs,
            `aed_eval.figures` (timing_accuracy, success_window, embeddings,
            error_correction).
        tasks: the tasks of every experiment, in order (default: each experiment's own: all
            seven, the paper's order, for main; the paper's task for each variant experiment).
        policies: the main experiment's policies, in order (default: the profile's); a case's
            jobs are the same whichever others are planned beside it.
        runs: root of everything written (default: runs/<profile>).
        results: where the variants' records go (default: results/<profile>).
        plan: print what is done and what is left; run nothing.
        policies_only: run only what the policies' novel success rates need (the collections,
            the scene encoder and localizer, the policies, their novel rollouts), to see a
            task's policies hours before its detectors; its cases stay open for a full run.
        workers: simulation processes for collection and rollouts.
        seed: root seed of every stage.
    """

    profile: Profile = "mini"
    experiments: tuple[str, ...] = ("main",)
    tasks: tuple[str, ...] = ()
    policies: tuple[str, ...] = ()
    runs: Path | None = None
    results: Path | None = None
    plan: bool = False
    policies_only: bool = False
    workers: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        from aed_eval.figures import FIGURES
        from aed_eval.variants import EXPERIMENTS

        check_profile(self.profile)
        known = ("main", *EXPERIMENTS, *FIGURES)
        unknown = [e for e in self.experiments if e not in known]
        if unknown or not self.experiments:
            raise ValueError(f"experiments={self.experiments}: known {known}")
        self.tasks = tuple(task_class(t).task_name for t in self.tasks)
        if len(set(self.tasks)) != len(self.tasks):
            raise ValueError(f"tasks={self.tasks}: a task is named twice")
        from aed_models.policies import POLICIES

        unknown = [p for p in self.policies if p not in POLICIES]
        if unknown or len(set(self.policies)) != len(self.policies):
            raise ValueError(f"policies={self.policies}: each once, of {list(POLICIES)}")
        if self.workers < 1:
            raise ValueError(f"workers={self.workers}: must be >= 1")
        if self.policies_only and self.experiments != ("main",):
            raise ValueError(f"policies_only: the main experiment's, not {self.experiments}")
        self.runs = Path(self.runs) if self.runs is not None else Path("runs") / self.profile
        self.results = (
            Path(self.results) if self.results is not None else Path("results") / self.profile
        )

    def tasks_of(self, experiment: str) -> tuple[str, ...]:
        """The tasks an experiment runs on: `tasks`, else the experiment's own."""
        from aed_eval.figures import FIGURES
        from aed_eval.variants import EXPERIMENTS

        if self.tasks:
            return self.tasks
        if experiment == "main":
            return PAPER_TASK_ORDER
        return (EXPERIMENTS.get(experiment) or FIGURES[experiment]).tasks

    def main_tasks(self) -> tuple[str, ...]:
        """Every task whose main stages run: the variants stand on them too."""
        wanted = {t for e in self.experiments for t in self.tasks_of(e)}
        order = self.tasks or PAPER_TASK_ORDER
        return tuple(t for t in order if t in wanted)


@dataclass
class Job:
    """One stage's config of one task: `fn(config)` does it (and resumes it).

    `experiment` names what planned it (`main`, a variant experiment or a figure); a main job's
    `case` is the policy of the (task, policy) case it serves, None when it serves every case
    of its task (the collections, the scene encoder and localizer, the detectors that read no
    policy).
    """

    task: str
    stage: str
    fn: Callable[[Any], Any]
    config: Any
    experiment: str = "main"
    case: str | None = None
    inputs: tuple[Job, ...] = dataclasses.field(default=(), repr=False, compare=False)

    @property
    def digest(self) -> str:
        """What the job does: its function, every field of its config, the config of the
        model a training builds (its `model_preset()`: the profile's sizes are not fields of
        the run) and the digests of the jobs whose outputs it reads (`inputs`). A field of
        `ADDED_FIELDS` at its value there is left out."""
        name = getattr(self.fn, "__qualname__", type(self.fn).__qualname__)
        config = {
            k: v
            for k, v in dataclasses.asdict(self.config).items()
            if k not in ADDED_FIELDS or v != ADDED_FIELDS[k]
        }
        record: dict[str, Any] = {"fn": f"{self.fn.__module__}.{name}", "config": config}
        model_preset = getattr(self.config, "model_preset", None)
        if model_preset is not None:
            record["model"] = dataclasses.asdict(model_preset())
        if self.inputs:
            record["inputs"] = sorted(j.digest for j in self.inputs)
        text = json.dumps(record, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def plan_jobs(cfg: ExperimentsConfig) -> list[Job]:
    """Every task's main stages, then every variant's, then the records read off the main
    runs; all configs built (so validated) before anything runs."""
    from aed_eval.demo import DemoConfig, plan_stages
    from aed_eval.figures import FIGURES, figure_jobs, run_figure
    from aed_eval.variants import EXPERIMENTS, experiment_stages, variant_stages

    jobs = []
    policies = {"policies": cfg.policies} if cfg.policies else {}
    protocols = {
        task: DemoConfig.from_preset(
            task, cfg.profile, runs=cfg.runs, workers=cfg.workers, seed=cfg.seed, **policies
        )
        for task in cfg.main_tasks()
    }
    for task, protocol in protocols.items():
        jobs += main_jobs(task, plan_stages(protocol), protocol.policies, RunLayout(cfg.runs))
    for name in cfg.experiments:
        if name not in EXPERIMENTS:
            continue
        experiment = EXPERIMENTS[name]
        for task in cfg.tasks_of(name):
            stages = experiment_stages(protocols[task], experiment)
            for variant in experiment.variants:
                if not variant.baseline:
                    stages += variant_stages(protocols[task], experiment, variant)
            for stage in stages:
                jobs += [Job(task, stage.name, fn, config, name) for fn, config in stage.jobs]
    for name in (n for n in cfg.experiments if n in FIGURES):
        for task in cfg.tasks_of(name):
            figures = figure_jobs(name, task, cfg.profile, cfg.runs, cfg.results)
            jobs += [Job(task, name, run_figure, job, name) for job in figures]
    return jobs


def case_policy(config: Any, task: str, policies: Sequence[str], layout: RunLayout) -> str | None:
    """The policy whose case a main job serves: the config's `policy` (a name, or a detector's
    policy checkpoint in the layout); None for a job that reads no policy."""
    policy = getattr(config, "policy", None)
    if policy is None or policy in policies:
        return policy
    for name in policies:
        if Path(policy) in (layout.policy(task, name), layout.policy(task, name).parent):
            return name
    raise ValueError(f"{task}: a job reads policy {policy!r}, not one of {list(policies)}")


def main_jobs(
    task: str, stages: Sequence[Any], policies: Sequence[str], layout: RunLayout
) -> list[Job]:
    """One task's main stages, case by case: first the jobs every case shares, then each
    policy's own (its training, its detectors, rollouts, calibrations and evaluation), so that
    a run stopped part-way has finished whole (task, policy) cases."""
    jobs: list[Job] = []
    for stage in stages:
        for fn, config in stage.jobs:
            case = case_policy(config, task, policies, layout)
            inputs = tuple(
                j for j in jobs if j.stage in READS.get(stage.name, ()) and j.case in (None, case)
            )
            jobs.append(Job(task, stage.name, fn, config, case=case, inputs=inputs))
    return [j for j in jobs if j.case is None] + [
        j for policy in policies for j in jobs if j.case == policy
    ]


class Ledger:
    """The finished jobs of a runs folder (`<runs>/experiments.json`), by digest."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.jobs: dict[str, dict[str, Any]] = {}
        if self.path.exists():
            try:
                body = json.loads(self.path.read_text())
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
                raise ValueError(f"{self.path}: corrupt ledger ({e}); move it away to rerun") from e
            if not isinstance(body, dict) or not isinstance(body.get("jobs"), dict):
                raise ValueError(f"{self.path}: not an experiments ledger (no 'jobs' object)")
            self.jobs = body["jobs"]

    def done(self, job: Job) -> bool:
        return job.digest in self.jobs

    def seconds(self, job: Job) -> float:
        """The wall time of the job's last run (0 when not done)."""
        return float(self.jobs.get(job.digest, {}).get("seconds", 0.0))

    def record(self, job: Job, seconds: float) -> None:
        self.jobs[job.digest] = {
            "task": job.task,
            "stage": job.stage,
            "seconds": round(seconds, 1),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        trajectory.write_json_atomic(self.path, {"jobs": self.jobs})


def case_jobs(jobs: Sequence[Job]) -> dict[tuple[str, str], list[Job]]:
    """Every main (task, policy) case and the jobs it needs: the task's shared ones and its
    own."""
    main = [j for j in jobs if j.experiment == "main"]
    keys = dict.fromkeys((j.task, j.case) for j in main if j.case is not None)
    return {
        (task, policy): [j for j in main if j.task == task and j.case in (None, policy)]
        for task, policy in keys
    }


def case_digest(jobs: Sequence[Job]) -> str:
    """What a case is: the digests of every job it needs."""
    text = "\n".join(sorted(j.digest for j in jobs))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def case_record_path(results: Path, task: str, policy: str) -> Path:
    """Where a main case's record is committed: `<results>/main/<task>_<policy>.json`."""
    return Path(results) / "main" / f"{task}_{policy}.json"


def committed_cases(jobs: Sequence[Job], results: Path) -> set[tuple[str, str]]:
    """The cases whose record under `results` was made by the same jobs (same digest): their
    numbers are in the repository, so their jobs need not run again, here or on another
    machine whose runs folder is empty."""
    from aed_eval.results import load_record

    committed = set()
    for case, needed in case_jobs(jobs).items():
        path = case_record_path(results, *case)
        if path.exists() and load_record(path).get("case_digest") == case_digest(needed):
            committed.add(case)
    return committed


def pending_jobs(jobs: Sequence[Job], committed: Collection[tuple[str, str]]) -> list[Job]:
    """The jobs still needed: all but the main jobs that serve committed cases only. A task that
    a variant or figure reads keeps every main job (they read the main run's files)."""
    readers = {j.task for j in jobs if j.experiment != "main"}
    cases = case_jobs(jobs)
    closed = {t for t, _ in cases} - {t for t, p in cases if (t, p) not in committed}

    def needed(job: Job) -> bool:
        if job.experiment != "main" or job.task in readers:
            return True
        if job.case is not None:
            return (job.task, job.case) not in committed
        return job.task not in closed  # a shared job: needed while any case of its task is open

    return [j for j in jobs if needed(j)]


def policy_jobs(jobs: Sequence[Job]) -> list[Job]:
    """The main jobs a policy's novel success rate needs: its training data, its visual heads,
    itself and its novel rollouts (not the base ones, which calibrate the detectors)."""
    return [
        j
        for j in jobs
        if j.stage in POLICY_STAGES
        and not (j.stage == "roll out policies" and j.config.split != "novel")
    ]


def status_lines(
    jobs: Sequence[Job], ledger: Ledger, committed: Collection[tuple[str, str]] = ()
) -> list[str]:
    """Per task and stage: jobs done (or not needed: their cases are committed) of planned, and
    the wall time the ledger measured for the done ones; then the totals and the committed
    cases."""
    pending = {id(j) for j in pending_jobs(jobs, committed)}
    planned, done, seconds = Counter(), Counter(), Counter()
    for job in jobs:
        planned[job.task, job.stage] += 1
        done[job.task, job.stage] += ledger.done(job) or id(job) not in pending
        seconds[job.task, job.stage] += ledger.seconds(job)
    lines = [
        f"{task:<15} {stage:<24} {done[task, stage]}/{n} done"
        + (f", {seconds[task, stage] / 60:.0f} min" if seconds[task, stage] else "")
        for (task, stage), n in planned.items()
    ]
    finished = sum(done.values())
    lines.append(
        f"{finished} of {len(jobs)} jobs done ({sum(seconds.values()) / 3600:.1f} h measured), "
        f"{len(jobs) - finished} left"
    )
    cases = case_jobs(jobs)
    if cases:
        names = [f"{t} / {p}" for t, p in cases if (t, p) in committed]
        lines.append(
            f"{len(names)} of {len(cases)} main cases committed"
            + (f": {', '.join(names)}" if names else "")
        )
    return lines


def run_jobs(jobs: Sequence[Job], ledger: Ledger, after: Callable[[Job], Any] | None = None) -> int:
    """Run every job the ledger does not hold, in order, recording each as it finishes; an
    error stops the run (what finished stays recorded). `after(job)` follows every job done,
    now or before. Returns the number of jobs run."""
    ran = 0
    for i, job in enumerate(jobs):
        if not ledger.done(job):
            logger.info("experiments: [%d/%d] %s: %s", i + 1, len(jobs), job.task, job.stage)
            start = time.perf_counter()
            job.fn(job.config)
            ledger.record(job, time.perf_counter() - start)
            ran += 1
        if after is not None:
            after(job)
    return ran


def case_record(
    cfg: ExperimentsConfig, task: str, policy: str, needed: Sequence[Job], ledger: Ledger
) -> dict[str, Any]:
    """A finished case's record: its evaluation (`aed evaluate`'s results.json), the jobs that
    made it with their wall times, and the command that resumes the grid."""
    evaluation = next(j for j in needed if j.case == policy and j.stage == "evaluate")
    path = Path(evaluation.config.out) / "results.json"
    try:
        results = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: unreadable evaluation ({e}); re-run aed evaluate") from e
    command = [
        "aed",
        "experiments",
        "--profile",
        cfg.profile,
        "--tasks",
        task,
        "--policies",
        policy,
    ]
    return {
        "kind": "main_case",
        "task": task,
        "policy": policy,
        "profile": cfg.profile,
        "command": shlex.join(command),
        "case_digest": case_digest(needed),
        "jobs": [
            {"stage": j.stage, "digest": j.digest, "seconds": ledger.jobs[j.digest]["seconds"]}
            for j in needed
        ],
        "results": results,
    }


def variant_records(cfg: ExperimentsConfig) -> list[Path]:
    """Write every variant experiment's records (one per task and policy) under `results`."""
    from aed_eval.results import write_result
    from aed_eval.variants import EXPERIMENTS, variants_record

    command = shlex.join(
        ["aed", "experiments", "--profile", cfg.profile, "--experiments", *cfg.experiments]
        + (["--tasks", *cfg.tasks] if cfg.tasks else [])
        + ["--runs", str(cfg.runs)]
    )
    written = []
    for name in (n for n in cfg.experiments if n in EXPERIMENTS):
        experiment = EXPERIMENTS[name]
        for task in cfg.tasks_of(name):
            for policy in experiment.policies:
                record = variants_record(cfg.runs, experiment, task, policy)
                record["command"] = command
                written += write_result(cfg.results / name / f"{task}_{policy}.json", record)
    return written


def experiments(cfg: Annotated[ExperimentsConfig, tyro.conf.arg(name="")]) -> int:
    """The paper's experiments (resumable): plan, run what is left, commit each finished main
    case under `results/<profile>/main/`, report."""
    from aed_eval.results import write_result
    from aed_eval.results.main import write_main_report

    jobs = plan_jobs(cfg)
    committed = committed_cases(jobs, cfg.results)
    if cfg.plan:  # the ledger is replaced atomically: readable while a run writes it
        print("\n".join(status_lines(jobs, Ledger(cfg.runs / LEDGER), committed)))
        return 0
    cfg.runs.mkdir(parents=True, exist_ok=True)
    cases = case_jobs(jobs)

    def commit(job: Job) -> None:
        case = (job.task, job.case)
        if job.experiment == "main" and job.stage == "evaluate" and case not in committed:
            record = case_record(cfg, job.task, job.case, cases[case], ledger)
            write_result(case_record_path(cfg.results, *case), record)
            committed.add(case)
            write_main_report(cfg.results / "main")  # the records and their report agree

    with folder_lock(cfg.runs / "experiments"):
        ledger = Ledger(cfg.runs / LEDGER)
        start = time.perf_counter()
        todo = pending_jobs(jobs, committed)
        ran = run_jobs(policy_jobs(todo) if cfg.policies_only else todo, ledger, after=commit)
        report = write_main_report(cfg.results / "main")
        records = variant_records(cfg)
    if report is not None:
        print(report.read_text())
    print("\n".join(status_lines(jobs, ledger, committed)))
    for record in records:
        if record.suffix == ".md":
            print(record.read_text())
    print(f"ran {ran} jobs in {(time.perf_counter() - start) / 60:.1f} min; report: {report}")
    return 0


def experiment_script(name: str, argv: Sequence[str] | None = None, doc: str = "") -> int:
    """`scripts/<name>.py`: `aed experiments --experiments <name>` with the command's other flags
    (`--profile`, `--tasks`, `--plan`, ...), so that each experiment has its own entry point;
    `--help` shows the script's `doc` above the command's flags."""
    from aed_eval.cli import main

    args = list(sys.argv[1:] if argv is None else argv)
    if any(a == "--experiments" or a.startswith("--experiments=") for a in args):
        raise SystemExit(f"scripts/{name}.py runs {name}; `aed experiments` runs any others")
    if doc and ("-h" in args or "--help" in args):
        print(doc)
    return main(["experiments", "--experiments", name, *args])

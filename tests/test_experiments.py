"""`aed experiments`: the main experiment's plan over every task, and a ledger that makes any
number of stops and restarts end with each job done once."""

from __future__ import annotations

import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from aed_eval.demo import Stage
from aed_eval.experiments import (
    LEDGER,
    POLICY_STAGES,
    READS,
    ExperimentsConfig,
    Job,
    Ledger,
    case_digest,
    case_jobs,
    main_jobs,
    plan_jobs,
    policy_jobs,
    run_jobs,
    status_lines,
)
from aed_eval.results import load_record
from aed_models.layout import RunLayout
from aed_tasks import PAPER_TASK_ORDER
from tests.helpers import aed

REPO = Path(__file__).resolve().parents[1]


def test_the_main_experiment_plans_every_task_in_the_protocols_order(tmp_path):
    jobs = plan_jobs(ExperimentsConfig(profile="mini", runs=tmp_path))
    assert [j.task for j in jobs][:: len(jobs) // 7] == list(PAPER_TASK_ORDER)
    stages = [j.stage for j in jobs if j.task == "PickPlace"]
    assert stages[0] == "collect base split" and stages[-1] == "evaluate"
    assert stages.count("train policies") == 3 and stages.count("evaluate") == 3
    assert len({j.digest for j in jobs}) == len(jobs)  # no two jobs alike
    assert all(
        str(j.config.out).startswith(str(tmp_path)) for j in jobs if hasattr(j.config, "out")
    )
    assert status_lines(jobs, Ledger(tmp_path / LEDGER))[-2:] == [
        f"0 of {len(jobs)} jobs done (0.0 h measured), {len(jobs)} left",
        "0 of 21 main cases committed",
    ]


@dataclass
class Step:
    name: str
    value: int = 0


class Recorder:
    """A job function that records what it ran and fails once on a chosen step."""

    def __init__(self, fail_on: str | None = None):
        self.ran: list[str] = []
        self.fail_on = fail_on

    def __call__(self, step: Step) -> None:
        if step.name == self.fail_on:
            self.fail_on = None
            raise RuntimeError(f"{step.name}: killed")
        self.ran.append(step.name)


def jobs_of(fn: Recorder, names: str, **changed: int) -> list[Job]:
    return [Job("T", "stage", fn, Step(n, changed.get(n, 0))) for n in names]


def test_a_stopped_run_resumes_where_it_stopped_and_a_changed_job_reruns(tmp_path):
    path = tmp_path / LEDGER
    fn = Recorder(fail_on="c")
    with pytest.raises(RuntimeError, match="c: killed"):
        run_jobs(jobs_of(fn, "abcd"), Ledger(path))
    assert fn.ran == ["a", "b"]
    assert run_jobs(jobs_of(fn, "abcd"), Ledger(path)) == 2  # a fresh process: c, d
    assert fn.ran == ["a", "b", "c", "d"]
    assert run_jobs(jobs_of(fn, "abcd"), Ledger(path)) == 0
    assert run_jobs(jobs_of(fn, "abcd", b=1), Ledger(path)) == 1  # b's config changed
    assert fn.ran[-1] == "b"
    ledger = Ledger(path)
    for entry in ledger.jobs.values():
        entry["seconds"] = 90.0
    assert status_lines(jobs_of(fn, "abcde"), ledger) == [
        "T               stage                    4/5 done, 6 min",  # what the ledger measured
        "4 of 5 jobs done (0.1 h measured), 1 left",
    ]


def test_the_digest_follows_every_field_of_the_config():
    fn = Recorder()
    job = Job("T", "stage", fn, Step("a"))
    assert job.digest == Job("T", "other name", fn, Step("a")).digest
    assert job.digest != dataclasses.replace(job, config=Step("a", 1)).digest


@dataclass
class WithPrecision(Step):
    precision: str = "fp32"


def test_a_field_added_later_keeps_the_digests_of_the_jobs_that_ran_without_it():
    """`precision` came after jobs were recorded: at fp32 (what they ran with) a job keeps its
    digest; at bf16 it is another job."""
    fn = Recorder()
    before = Job("T", "stage", fn, Step("a")).digest
    assert Job("T", "stage", fn, WithPrecision("a")).digest == before
    assert Job("T", "stage", fn, WithPrecision("a", precision="bf16")).digest != before


@dataclass
class Reads:
    """A stand-in stage config: the policy it reads (None: none) and a value to change."""

    name: str
    policy: str | None = None
    value: int = 0


def two_cases(fn: Recorder, **changed: int) -> list[Job]:
    """One task's main stages over two policies, `changed` naming the jobs whose value moves."""

    def stage(name: str, *configs: Reads) -> Stage:
        return Stage(
            name, [(fn, dataclasses.replace(c, value=changed.get(c.name, 0))) for c in configs]
        )

    return main_jobs(
        "T",
        [
            stage("collect base split", Reads("collect")),
            stage("train policies", Reads("train dct", "dct"), Reads("train scan", "scan")),
            stage("train detectors", Reads("lstm_ed"), Reads("probe scan", "scan")),
            stage("roll out policies", Reads("roll dct", "dct"), Reads("roll scan", "scan")),
        ],
        ("dct", "scan"),
        RunLayout(Path("runs")),
    )


def test_a_retrained_policy_reruns_what_reads_it_and_nothing_else(tmp_path):
    every = {j.stage for j in plan_jobs(ExperimentsConfig(profile="mini", runs=tmp_path))}
    assert set(READS) | {s for stages in READS.values() for s in stages} <= every
    ledger, fn = Ledger(tmp_path / LEDGER), Recorder()
    assert run_jobs(two_cases(fn), ledger) == 7
    assert run_jobs(two_cases(fn, **{"train scan": 1}), ledger) == 3
    assert fn.ran[7:] == ["train scan", "probe scan", "roll scan"]
    assert run_jobs(two_cases(fn, **{"train scan": 1, "lstm_ed": 1}), ledger) == 1  # read by none
    assert run_jobs(two_cases(fn, collect=1), ledger) == 7  # all read the base data
    jobs = plan_jobs(ExperimentsConfig(profile="mini", tasks=("PressButton",), runs=tmp_path))
    roll = next(j for j in jobs if j.stage == "roll out policies" and j.case == "scan")
    assert {(j.stage, j.case) for j in roll.inputs} == {
        ("collect novel split", None),
        ("train policies", "scan"),
    }


def test_a_changed_model_preset_retrains_its_model_and_what_reads_it(tmp_path, monkeypatch):
    """A model's sizes are its preset's, not fields of the training run: changing the preset
    (here the localizer's cells) changes that training's job and those reading it, and leaves
    the collections and the scene encoder done."""
    from aed_models.localizer import LocalizerConfig

    def digests() -> dict[tuple[str, str | None], set[str]]:
        cfg = ExperimentsConfig(profile="mini", tasks=("PressButton",), runs=tmp_path)
        out: dict[tuple[str, str | None], set[str]] = {}
        for job in plan_jobs(cfg):
            out.setdefault((job.stage, job.case), set()).add(job.digest)
        return out

    before = digests()
    preset = LocalizerConfig.preset
    monkeypatch.setattr(
        LocalizerConfig,
        "preset",
        classmethod(lambda cls, profile: dataclasses.replace(preset(profile), stride=8)),
    )
    after = digests()
    changed = {key for key in before if before[key] != after[key]}
    assert ("train target localizer", None) in changed
    assert {("train policies", p) for p in ("naive_dc", "dct", "scan")} <= changed
    assert not changed & {
        ("collect base split", None),
        ("collect novel split", None),
        ("train scene encoder", None),
    }


def test_a_corrupt_ledger_is_named_in_one_line(tmp_path, caplog, capsys):
    (tmp_path / LEDGER).write_text("{not json")
    status, errors, _ = aed(["experiments", "--plan", "--runs", str(tmp_path)], caplog, capsys)
    assert status == 2 and len(errors) == 1 and f"{Path(tmp_path / LEDGER)}: corrupt" in errors[0]
    (tmp_path / LEDGER).write_text("[]")
    status, errors, _ = aed(["experiments", "--plan", "--runs", str(tmp_path)], caplog, capsys)
    assert status == 2 and "not an experiments ledger" in errors[0]


def test_the_plan_reads_the_ledger_while_a_run_holds_the_folder(tmp_path, caplog, capsys):
    from aed_tasks.locks import folder_lock

    with folder_lock(tmp_path / "experiments"):
        status, errors, out = aed(
            ["experiments", "--plan", "--tasks", "PressButton", "--runs", str(tmp_path)],
            caplog,
            capsys,
        )
    assert status == 0 and not errors and "0 of 34 jobs done (0.0 h measured), 34 left" in out


def test_unknown_or_repeated_tasks_are_refused():
    with pytest.raises(ValueError, match="Nope"):
        ExperimentsConfig(tasks=("Nope",))
    with pytest.raises(ValueError, match="named twice"):
        ExperimentsConfig(tasks=("PickPlace", "PickPlace"))


def test_the_variants_plan_their_detectors_beside_the_main_stages_of_their_task(tmp_path):
    from aed_eval.variants import EXPERIMENTS, VariantTraining
    from aed_models.detectors import DETECTORS

    cfg = ExperimentsConfig(profile="mini", experiments=("probe_components",), runs=tmp_path)
    jobs = plan_jobs(cfg)
    assert {j.task for j in jobs} == {"PickPlace"}  # the paper's task, its main stages first
    assert jobs[0].stage == "collect base split"
    trainings = [j.config for j in jobs if isinstance(j.config, VariantTraining)]
    assert [t.training.detector for t in trainings] == ["probe"] * 3
    assert [t.model for t in trainings] == [
        v.model for v in EXPERIMENTS["probe_components"].variants[:3]
    ]
    assert all(
        str(t.training.out).startswith(str(tmp_path / "variants" / "probe_components"))
        for t in trainings
    )
    assert len({j.digest for j in jobs}) == len(jobs)
    for experiment in EXPERIMENTS.values():  # every variant's model overrides are valid
        for variant in experiment.variants:
            for detector in experiment.detectors if variant.model else ():
                DETECTORS.preset(detector, "mini", **variant.model)
    seeds = plan_jobs(ExperimentsConfig(profile="mini", experiments=("seeds",), runs=tmp_path))
    trained = [j.config.training for j in seeds if isinstance(j.config, VariantTraining)]
    assert sorted({t.seed for t in trained}) == [1, 2, 3, 4] and len(trained) == 4 * 10
    with pytest.raises(ValueError, match=r"experiments=\('ablation',\): known"):
        ExperimentsConfig(experiments=("ablation",))


def test_the_records_read_off_the_main_runs_come_after_the_stages_they_read(tmp_path):
    from aed_eval.figures import FigureJob
    from aed_tasks import PAPER_TASK_ORDER

    cfg = ExperimentsConfig(
        experiments=("timing_accuracy", "embeddings", "error_correction"),
        runs=tmp_path / "runs",
        results=tmp_path / "results",
    )
    jobs = plan_jobs(cfg)
    figures = [(i, j) for i, j in enumerate(jobs) if isinstance(j.config, FigureJob)]
    cases = [(j.stage, j.task, j.config.config.policy) for _, j in figures]
    assert cases[-2:] == [
        ("embeddings", "PickPlace", "scan"),
        ("error_correction", "PressButton", "dct"),
    ]
    timing = [c for c in cases if c[0] == "timing_accuracy"]
    assert len(timing) == 3 * 7 and cfg.main_tasks() == PAPER_TASK_ORDER  # timing: every case
    last_evaluation = max(i for i, j in enumerate(jobs) if j.stage == "evaluate")
    assert min(i for i, _ in figures) > last_evaluation
    job = figures[-1][1].config
    assert job.config.out == tmp_path / "results" / "error_correction"
    assert job.command.startswith("python scripts/error_correction.py --profile mini")


def test_the_main_stages_run_case_by_case_after_what_the_cases_share(tmp_path):
    jobs = plan_jobs(ExperimentsConfig(profile="mini", tasks=("PressButton",), runs=tmp_path))
    cases = [j.case for j in jobs]
    shared = cases.count(None)
    assert set(cases[:shared]) == {None}  # collections, encoder, localizer, 4 detectors
    assert [j.stage for j in jobs[:shared]].count("train detectors") == 4
    owned = cases[shared:]
    assert owned == sorted(owned, key=["naive_dc", "dct", "scan"].index)  # one case at a time
    for policy in ("naive_dc", "dct", "scan"):
        stages = [j.stage for j in jobs if j.case == policy]
        assert stages[0] == "train policies" and stages[-1] == "evaluate"
        assert stages.count("train detectors") == 2  # probe and rnd_oe on its features
    assert list(case_jobs(jobs)) == [("PressButton", p) for p in ("naive_dc", "dct", "scan")]
    alone = plan_jobs(
        ExperimentsConfig(tasks=("PressButton",), policies=("scan",), runs=tmp_path)
    )  # one case planned alone is the same case
    assert list(case_jobs(alone)) == [("PressButton", "scan")]
    assert case_digest(case_jobs(alone)["PressButton", "scan"]) == case_digest(
        case_jobs(jobs)["PressButton", "scan"]
    )


@dataclass
class Evaluation:
    """A stand-in evaluation job: it writes `results.json` (a real one, relabelled) to `out`."""

    name: str
    out: Path
    policy: str


def grid(fn: Recorder, runs: Path, **changed: int) -> list[Job]:
    """Two cases of one task: a shared collection, then each policy's training and evaluation."""

    def job(name: str, case: str | None, config: object) -> Job:
        return Job("PressButton", name.split()[0], fn, config, case=case)

    jobs = [job("collect", None, Step("collect"))]
    for policy in ("dct", "scan"):
        jobs += [
            job("train", policy, Step(f"train {policy}", changed.get(policy, 0))),
            job("evaluate", policy, Evaluation(f"evaluate {policy}", runs / policy, policy)),
        ]
    return jobs


class Evaluator(Recorder):
    def __call__(self, step: Step | Evaluation) -> None:
        super().__call__(step)
        if isinstance(step, Evaluation):
            body = json.loads((REPO / "results/protocol/PressButton_scan/results.json").read_text())
            step.out.mkdir(parents=True)
            (step.out / "results.json").write_text(json.dumps({**body, "policy": step.policy}))


def test_policies_only_plans_the_policies_and_their_novel_rollouts_and_no_detector(tmp_path):
    jobs = plan_jobs(ExperimentsConfig(profile="mini", tasks=("PressButton",), runs=tmp_path))
    assert set(POLICY_STAGES) <= {j.stage for j in jobs}  # every name is a planned stage
    chosen = policy_jobs(jobs)
    stages = [j.stage for j in chosen]
    assert set(stages) == set(POLICY_STAGES)  # no detector, calibration or evaluation
    rollouts = [j.config for j in chosen if j.stage == "roll out policies"]
    assert [(r.policy, r.split) for r in rollouts] == [
        (p, "novel") for p in ("naive_dc", "dct", "scan")
    ]
    assert stages.count("train policies") == 3
    assert [j for j in jobs if j in chosen] == chosen  # the plan's order, a subset of it
    with pytest.raises(ValueError, match="policies_only"):
        ExperimentsConfig(experiments=("seeds",), policies_only=True)


def test_a_finished_case_is_committed_and_never_recomputed_on_an_empty_machine(
    tmp_path, monkeypatch, capsys
):
    """Runs folders do not outlive a machine here: a finished case's record under results/ is
    what says it is done, and a fresh runs folder runs only the cases still open."""
    import aed_eval.experiments as experiments_module
    from aed_eval.experiments import experiments
    from aed_eval.results import stale_markdown

    results, fn = tmp_path / "results", Evaluator(fail_on="evaluate scan")

    def run(**changed: int) -> None:
        monkeypatch.setattr(
            experiments_module, "plan_jobs", lambda cfg: grid(fn, cfg.runs, **changed)
        )
        experiments(ExperimentsConfig(runs=tmp_path / "runs", results=results))

    def new_machine() -> None:  # the same commands, nothing left of the runs folder
        shutil.rmtree(tmp_path / "runs")
        fn.ran.clear()

    with pytest.raises(RuntimeError, match="evaluate scan: killed"):
        run()
    record = load_record(results / "main" / "PressButton_dct.json")
    assert record["kind"] == "main_case" and record["results"]["policy"] == "dct"
    assert [j["stage"] for j in record["jobs"]] == ["collect", "train", "evaluate"]
    assert not (results / "main" / "PressButton_scan.json").exists()
    assert "PressButton / dct" in (results / "main" / "report.md").read_text()
    figures = ("report.png", "PressButton_dct_auroc.png", "PressButton_dct_roc.png")
    assert all((results / "main" / f).stat().st_size > 0 for f in figures)

    new_machine()
    run()
    assert fn.ran == ["collect", "train scan", "evaluate scan"]
    report = (results / "main" / "report.md").read_text()
    assert "PressButton / dct" in report and "PressButton / scan" in report
    assert "2 of 2 main cases committed" in capsys.readouterr().out
    assert stale_markdown(results) == []

    new_machine()
    run()
    assert fn.ran == []
    run(scan=1)  # scan's training changed: its case is open again, dct's is not
    assert fn.ran == ["collect", "train scan", "evaluate scan"]

    (results / "main" / "report.md").write_text("edited by hand\n")
    assert stale_markdown(results) == [
        f"{results / 'main' / 'report.md'}: differs from what the cases beside it render to"
    ]


def test_every_experiment_has_its_own_script(tmp_path, capsys, caplog):
    from aed_eval.experiments import experiment_script
    from aed_eval.figures import FIGURES
    from aed_eval.variants import EXPERIMENTS

    scripts = {p.stem: p.read_text() for p in (REPO / "scripts").glob("*.py")}
    for name in ("main", *EXPERIMENTS):
        script = scripts["main_experiment" if name == "main" else name]
        assert f'experiment_script("{name}", doc=__doc__)' in script
    assert set(FIGURES) <= set(scripts)
    assert experiment_script("probe_components", ["--plan", "--runs", str(tmp_path)]) == 0
    assert "probe_components / + L_pat: train detectors 0/1 done" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        experiment_script("seeds", ["--help"], doc="Stability over five seeds")
    assert capsys.readouterr().out.startswith("Stability over five seeds")
    with pytest.raises(SystemExit, match="scripts/seeds.py runs seeds"):
        experiment_script("seeds", ["--experiments", "main"])
    assert experiment_script("ablation", ["--plan", "--runs", str(tmp_path)]) == 2
    assert "experiments=('ablation',): known" in caplog.text

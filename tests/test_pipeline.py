"""The whole protocol at toy sizes (`aed demo`'s stages), and its bad-input errors.

One Press Button pipeline: base collection, a NaiveDC policy, PrObe and LSTMED, novel
demonstrations and labelled episodes, rollouts, calibration, evaluation and the report.
The models are barely trained: this checks that the stages fit together and that every
file the next stage reads is there and consistent, not what the numbers are.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aed_eval.demo import DemoConfig, run_demo
from aed_eval.scoring import load_checked_detector
from aed_models.layout import RunLayout
from tests.helpers import aed, load_script

AED = str(Path(sys.executable).with_name("aed"))
TASK = "PressButton"


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> tuple[DemoConfig, Path]:
    runs = tmp_path_factory.mktemp("runs")
    cfg = DemoConfig.from_preset(
        task=TASK,
        policies=("naive_dc",),
        detectors=("probe", "lstm_ed"),
        runs=runs,
        train_envs=1,
        calibration_envs=1,
        novel_envs=1,
        num_demos=1,
        num_successes=2,
        num_failures=2,
        num_explore=1,
        labelled=1,
        rollouts=2,
        calibration_rollouts=2,
        encoder_epochs=1,
        localizer_epochs=1,
        policy_epochs=1,
        detector_epochs=1,
        horizon=30,
        alphas=(0.5,),
        workers=1,
    )
    report, times = run_demo(cfg)
    assert set(times) >= {
        "collect base split",
        "train scene encoder",
        "train target localizer",
        "train policies",
        "train detectors",
        "evaluate",
        "report",
    }
    return cfg, report


@pytest.mark.slow
def test_every_stage_leaves_what_the_next_reads(pipeline):
    cfg, report = pipeline
    layout = RunLayout(cfg.runs)
    results = json.loads((layout.evaluation(TASK, "naive_dc") / "results.json").read_text())
    assert results["rollouts"]["count"] == 2 and results["rollouts"]["horizon"] == 30
    assert results["endings"] == ["horizon", "success"] and not results["diagnostic"]
    assert set(results["detectors"]) == {"probe", "lstm_ed"} and set(results["references"]) == {
        "time_only",
        "random",
    }
    assert set(results["labelled_references"]) == {"time_only", "random"}
    for row in results["detectors"].values():
        rates = row["horizon"]["calibrated"]["expert@0.5"]
        assert 0.0 <= rates["tpr"] <= 1.0 and len(row["horizon"]["auroc_interval"]) == 2
        assert 0.0 <= row["labelled"]["frame_auroc"] <= 1.0
        assert len(row["labelled"]["time_matched_auroc_interval"]) == 2
        assert sum(row["labelled"]["delays"]["expert@0.5"]["counts"].values()) == 1
    folder = layout.detector(TASK, "probe", "naive_dc").parent
    expert = json.loads((folder / "calibration-expert.json").read_text())
    assert (
        expert["envs"] == [1]
        and expert["num_rollouts"] == 2
        and np.isfinite(expert["thresholds"]["0.5"])
    )
    policy = json.loads(
        (folder / "calibration.json").read_text()
    )  # an untrained policy never succeeds
    assert policy["envs"] == [1] and (policy["num_rollouts"], policy["of_rollouts"]) == (0, 2)
    assert policy["thresholds"] == {"0.5": None}
    scores = json.loads((layout.evaluation(TASK, "naive_dc") / "scores.json").read_text())
    assert [len(s) for s in scores["rollouts"]["scores"]["probe"]] == [31, 31]
    text = report.read_text()
    assert "| PressButton / naive_dc |" in text and "probe" in text and "*time_only*" in text
    for figure in (
        "roc_PressButton_naive_dc.png",
        "auroc_PressButton_naive_dc.png",
        "overview.png",
    ):
        assert (report.parent / figure).stat().st_size > 0


@pytest.mark.slow
def test_detectors_of_another_policy_or_task_are_refused(pipeline):
    cfg, _ = pipeline
    layout = RunLayout(cfg.runs)
    probe = layout.detector(TASK, "probe", "naive_dc")
    with pytest.raises(ValueError, match="not on the evaluated checkpoint"):
        load_checked_detector(probe, "probe", TASK, policy_sha256="0" * 64)
    with pytest.raises(ValueError, match="trained for task 'PressButton', not 'PickPlace'"):
        load_checked_detector(
            layout.detector(TASK, "lstm_ed", "naive_dc"), "lstm_ed", "PickPlace", ""
        )


@pytest.mark.slow
def test_a_rerun_reuses_finished_stages(pipeline):
    cfg, _ = pipeline
    checkpoint = RunLayout(cfg.runs).policy(TASK, "naive_dc")
    encoder = RunLayout(cfg.runs).encoder(TASK)
    before = checkpoint.stat().st_mtime_ns, encoder.stat().st_mtime_ns
    _, times = run_demo(cfg)
    assert times["collect base split"] < 30 and times["roll out policies"] < 30, times
    assert (checkpoint.stat().st_mtime_ns, encoder.stat().st_mtime_ns) == before  # not retrained


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["evaluate", "--task", "Juggle"], "task='Juggle'"),
        (["evaluate", "--task", TASK, "--policy", "juggle"], "unknown policy 'juggle'"),
        (["evaluate", "--task", TASK, "--detectors", "juggle"], "detectors=['juggle']"),
        (["rollout", "--task", TASK, "--policy", "juggle"], "unknown policy 'juggle'"),
        (["report", "--results", "/nonexistent/results.json"], "/nonexistent/results.json"),
    ],
)
def test_bad_input_is_one_line_and_status_2(args, named, caplog, capsys):
    status, errors, _ = aed(args, caplog, capsys)
    assert status == 2 and len(errors) == 1 and named in errors[0], errors
    assert "\n" not in errors[0]


@pytest.mark.slow
def test_missing_rollouts_and_mismatched_checkpoints_are_named(pipeline, tmp_path):
    cfg, _ = pipeline
    runs = tmp_path / "runs"
    shutil.copytree(cfg.runs, runs)
    shutil.rmtree(RunLayout(runs).rollouts(TASK, "naive_dc"))
    result = subprocess.run(
        [
            AED,
            "evaluate",
            "--task",
            TASK,
            "--policy",
            "naive_dc",
            "--detectors",
            "probe",
            "--runs",
            str(runs),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 2 and "no such collection folder" in result.stderr, result.stderr


@pytest.mark.slow
@pytest.mark.parametrize(
    ("detector", "change", "named"),
    [
        ("probe", {"policy_sha256": "0" * 64}, "not on the evaluated checkpoint"),
        ("lstm_ed", {"task": "PickPlace"}, "trained for task 'PickPlace', not 'PressButton'"),
    ],
)
def test_a_detector_of_another_policy_or_task_is_one_line_and_status_2(
    pipeline, tmp_path, detector, change, named
):
    from aed_models.checkpoint import load_checkpoint, save_checkpoint
    from aed_models.detectors import FAMILY

    cfg, _ = pipeline
    runs = tmp_path / "runs"
    shutil.copytree(cfg.runs, runs)
    path = RunLayout(runs).detector(TASK, detector, "naive_dc")
    ckpt = load_checkpoint(path, family=FAMILY, name=detector)
    save_checkpoint(
        path,
        family=FAMILY,
        name=detector,
        config=ckpt.config,
        state_dict=ckpt.state_dict,
        extra={**ckpt.extra, **change},
    )
    result = subprocess.run(
        [
            AED,
            "evaluate",
            "--task",
            TASK,
            "--policy",
            "naive_dc",
            "--detectors",
            detector,
            "--runs",
            str(runs),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 2 and named in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_heldout_auroc_script_scores_every_detector_of_a_runs_layout(pipeline, tmp_path):
    cfg, _ = pipeline
    script = load_script("heldout_auroc")
    out = tmp_path / "auroc.json"
    config = {
        "task": TASK,
        "runs": cfg.runs,
        "envs": (0,),
        "policies": ("naive_dc",),
        "detectors": ("probe", "lstm_ed"),
        "num_demos": 1,
        "out": out,
    }
    with pytest.raises(ValueError, match=r"policy naive_dc trained on base environments \[0\]"):
        script.main(
            script.Config(**config)
        )  # only environment 0 has failures, and the models trained there
    results = script.main(script.Config(**config, allow_trained_envs=True))
    assert results["trained_env_overlap"]["policy naive_dc"] == [0]
    assert results["failures"] == 2 and json.loads(out.read_text()) == results
    for kind in ("auroc", "time_matched"):
        assert 0.0 <= results[kind]["time_only"] <= 1.0 and set(results[kind]["naive_dc"]) == {
            "probe",
            "lstm_ed",
        }
    arrays = np.load(out.with_suffix(".npz"))
    assert len(arrays["naive_dc/probe"]) == len(arrays["labels"]) == arrays["lengths"].sum()


def command_line(cfg: DemoConfig) -> list[str]:
    """The flags that make `aed demo` build `cfg`."""
    import dataclasses

    args = []
    for field in dataclasses.fields(cfg):
        value, flag = getattr(cfg, field.name), "--" + field.name.replace("_", "-")
        if isinstance(value, bool):
            args.append(flag if value else "--no-" + flag[2:])
        elif isinstance(value, (tuple, list)):
            args += [flag, *map(str, value)]
        elif value is not None:
            args += [flag, str(value)]
    return args


@pytest.mark.slow
def test_demo_as_a_command_reuses_the_finished_stages(pipeline):
    cfg, report = pipeline
    checkpoint = RunLayout(cfg.runs).policy(TASK, "naive_dc")
    before = checkpoint.stat().st_mtime_ns
    result = subprocess.run(
        [AED, "demo", *command_line(cfg)], capture_output=True, text=True, timeout=900
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "| PressButton / naive_dc |" in result.stdout and "stage times:" in result.stdout
    assert checkpoint.stat().st_mtime_ns == before  # not retrained
    assert json.loads((cfg.runs / "demo.json").read_text())["report"] == str(report)


@pytest.mark.slow
def test_monitor_as_a_command_stops_at_the_alarm_and_writes_its_video(pipeline, tmp_path):
    cfg, _ = pipeline
    video = tmp_path / "monitor.mp4"
    args = ["--task", TASK, "--policy", "naive_dc", "--detector", "lstm_ed", "--env-index", "0"]
    result = subprocess.run(
        [AED, "monitor", *args, "--num-demos", "1", "--threshold", "0", "--runs", str(cfg.runs)]
        + ["--out", str(video)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"{video}: " in result.stdout and "alarms=1" in result.stdout, result.stdout
    assert video.stat().st_size > 0


@pytest.mark.slow
def test_report_as_a_command_writes_the_table_of_an_evaluation(pipeline, tmp_path):
    cfg, _ = pipeline
    results = RunLayout(cfg.runs).evaluation(TASK, "naive_dc") / "results.json"
    out = tmp_path / "report"
    result = subprocess.run(
        [AED, "report", "--results", str(results), "--out", str(out), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "| PressButton / naive_dc |" in (out / "report.md").read_text()


@pytest.mark.slow
def test_timing_accuracy_script_renders_an_evaluation_of_the_pipeline(pipeline, tmp_path):
    from aed_eval.results import stale_markdown

    cfg, _ = pipeline
    script = load_script("timing_accuracy")
    config = script.Config(
        profile="demo",
        runs=cfg.runs,
        tasks=(TASK,),
        policies=("naive_dc",),
        alpha=0.5,
        calibration="expert",  # the tiny pipeline's policy has no held-out success
    )
    config.out = tmp_path
    written = script.main(config)
    record = json.loads(written[0].read_text())
    assert record["kind"] == "timing_accuracy" and set(record["thresholds"]) == {"probe", "lstm_ed"}
    assert record["panels"] and all(len(p["scores"]["probe"]) > 1 for p in record["panels"])
    assert [p.suffix for p in written] == [".json", ".md", ".png"]
    assert stale_markdown(tmp_path) == []


@pytest.mark.slow
def test_success_window_script_reads_an_evaluation_and_its_rollouts(pipeline, tmp_path):
    from aed_eval.results import stale_markdown
    from aed_eval.results.success_window import success_steps
    from aed_models.layout import RunLayout

    cfg, _ = pipeline
    script = load_script("success_window")
    config = script.Config(profile="demo", runs=cfg.runs, tasks=(TASK,), policies=("naive_dc",))
    config.out = tmp_path
    written = script.main(config)
    record = json.loads(written[0].read_text())
    assert record["kind"] == "success_window" and record["policy"] == "naive_dc"
    assert record["successes"] + record["failures"] > 0 and stale_markdown(tmp_path) == []
    # every scored success has its first success step in the stored rollouts
    layout = RunLayout(cfg.runs)
    steps = success_steps(layout.rollouts(TASK, "naive_dc"), "naive_dc", record["policy_sha256"])
    assert len(steps) == record["successes"]
    assert all(0 <= k <= 200 for k in steps.values())


@pytest.mark.slow
def test_a_detector_variant_trains_and_evaluates_beside_the_main_run(pipeline, tmp_path):
    from aed_eval.results import stale_markdown, write_result
    from aed_eval.variants import (
        DetectorExperiment,
        Variant,
        variant_root,
        variant_stages,
        variants_record,
    )

    cfg, _ = pipeline
    experiment = DetectorExperiment(
        "ra_check",
        "RA",
        tasks=(TASK,),
        policies=("naive_dc",),
        detectors=("probe", "lstm_ed"),
        variants=(Variant("without RA", {"augment": False}), Variant("with RA", baseline=True)),
    )
    main_detector = RunLayout(cfg.runs).detector(TASK, "probe", "naive_dc")
    before = main_detector.stat().st_mtime_ns
    stages = variant_stages(cfg, experiment, experiment.variants[0])
    for stage in stages:
        for fn, job in stage.jobs:
            fn(job)
    root = variant_root(cfg.runs, "ra_check", experiment.variants[0])
    assert (root / TASK / "policies").is_symlink() and not (root / TASK / "detectors").is_symlink()
    assert RunLayout(root).detector(TASK, "probe", "naive_dc").is_file()
    assert main_detector.stat().st_mtime_ns == before  # the main run's detectors untouched
    stages[0].jobs[0][0](stages[0].jobs[0][1])  # linking again is a no-op

    record = variants_record(cfg.runs, experiment, TASK, "naive_dc")
    assert list(record["variants"]) == ["without RA", "with RA"]
    assert record["paper"] is None  # the paper's RA numbers are a figure
    assert set(record["variants"]["with RA"]["paper_ending"]) == {"probe", "lstm_ed"}
    for variant in record["variants"].values():  # the labelled episodes, scored by each variant
        assert set(variant["labelled"]) == {"probe", "lstm_ed"}
    written = write_result(tmp_path / "ra.json", record)
    assert "| probe |" in written[1].read_text() and stale_markdown(tmp_path) == []


@pytest.mark.slow
def test_error_correction_replays_the_stored_rollouts_and_corrects_at_alarms(pipeline, tmp_path):
    from aed_eval.correction import CorrectionConfig, correction_record
    from aed_eval.results import write_result

    cfg, _ = pipeline
    pilot = dict(task=TASK, policy="naive_dc", detectors=("lstm_ed",), num_demos=1, runs=cfg.runs)
    never = correction_record(CorrectionConfig(**pilot, threshold=2.0))  # scores stay <= 1
    quiet = never["detectors"]["lstm_ed"]
    assert never["rollouts"] == 2 and quiet["alarmed"] == 0
    assert quiet["successes"] == never["successes_without"]  # the replays are the stored ones
    assert quiet["quiet_replays_changed"] == 0
    always = correction_record(CorrectionConfig(**pilot, threshold=0.0))
    assert always["detectors"]["lstm_ed"]["alarmed"] == 2
    replays = json.loads(
        (
            RunLayout(cfg.runs).evaluation(TASK, "naive_dc").parent / "correction" / "lstm_ed.json"
        ).read_text()
    )["replays"]
    assert all(r["corrections"] == 1 and r["first_alarm"] == 0 for r in replays)
    written = write_result(tmp_path / "correction.json", always)
    assert "| lstm_ed |" in written[1].read_text()


@pytest.mark.slow
def test_embeddings_script_maps_the_labelled_novel_episodes(pipeline, tmp_path):
    from aed_eval.embeddings import EmbeddingsConfig, embeddings_record

    cfg, _ = pipeline
    figure = dict(task=TASK, policy="naive_dc", detectors=("probe", "lstm_ed"), runs=cfg.runs)
    record = embeddings_record(EmbeddingsConfig(**figure, num_episodes=2, num_demos=1))
    frames = sum(e["frames"] for e in record["episodes"])
    assert [e["onset_frame"] is None for e in record["episodes"]] == [True, False]
    for d in ("probe", "lstm_ed"):
        assert len(record["detectors"][d]["points"]) == frames
        assert 0.0 <= record["detectors"][d]["label_agreement"] <= 1.0
    with pytest.raises(ValueError, match="4 episodes asked for"):
        embeddings_record(EmbeddingsConfig(**figure, num_episodes=4, num_demos=1))


@pytest.mark.slow
def test_a_rollout_variant_rolls_out_with_suboptimal_demonstrations(pipeline, tmp_path):
    from aed_eval.variants import (
        DetectorExperiment,
        Variant,
        experiment_stages,
        variant_root,
        variant_stages,
        variants_record,
    )
    from aed_tasks import trajectory

    cfg, _ = pipeline
    experiment = DetectorExperiment(
        "quality_check",
        "quality",
        tasks=(TASK,),
        policies=("naive_dc",),
        detectors=("probe", "lstm_ed"),
        variants=(
            Variant("optimal", baseline=True),
            Variant("sub-optimal", suboptimal_demos="all"),
        ),
    )
    for stage in experiment_stages(cfg, experiment) + variant_stages(
        cfg, experiment, experiment.variants[1]
    ):
        for fn, job in stage.jobs:
            fn(job)
    layout = RunLayout(variant_root(cfg.runs, "quality_check", experiment.variants[1]))
    assert (layout.root / TASK / "detectors").is_symlink()
    assert not (layout.root / TASK / "rollouts").is_symlink()
    demos = trajectory.scan_collection(RunLayout(cfg.runs).data(TASK, "novel-suboptimal"))
    assert [r.suboptimal for r in demos.episodes()] == [True]
    rollouts = trajectory.scan_collection(layout.rollouts(TASK, "naive_dc", "novel"))
    assert len(list(rollouts.episodes())) == 2
    results = json.loads((layout.evaluation(TASK, "naive_dc") / "results.json").read_text())
    assert results["demos"] == {"count": 1, "suboptimal": 1}
    record = variants_record(cfg.runs, experiment, TASK, "naive_dc")
    assert list(record["variants"]) == ["optimal", "sub-optimal"]


@pytest.mark.slow
def test_a_viewpoint_variant_sees_every_novel_episode_through_the_shifted_camera(pipeline):
    import h5py

    from aed_eval.variants import (
        EXPERIMENTS,
        DetectorExperiment,
        camera_data,
        experiment_stages,
        variant_root,
        variant_stages,
    )
    from aed_tasks import trajectory

    cfg, _ = pipeline
    shifted = EXPERIMENTS["viewpoint"].variants[1]
    experiment = DetectorExperiment(
        "viewpoint_check",
        "viewpoint",
        tasks=(TASK,),
        policies=("naive_dc",),
        detectors=("probe", "lstm_ed"),
        variants=(EXPERIMENTS["viewpoint"].variants[0], shifted),
    )
    for stage in experiment_stages(cfg, experiment) + variant_stages(cfg, experiment, shifted):
        for fn, job in stage.jobs:
            fn(job)
    seen = trajectory.scan_collection(RunLayout(cfg.runs).data(TASK, camera_data("front_shift")))
    assert sorted(r.role for r in seen.episodes()) == ["agent_failure", "agent_success", "demo"]
    main_demos = trajectory.scan_collection(RunLayout(cfg.runs).data(TASK, "novel")).episodes()
    shifted_demo = next(r for r in seen.episodes() if r.role == "demo")
    assert shifted_demo.seed == main_demos[0].seed  # the same episode, seen from elsewhere
    layout = RunLayout(variant_root(cfg.runs, "viewpoint_check", shifted))
    rollouts = trajectory.scan_collection(layout.rollouts(TASK, "naive_dc", "novel")).episodes()
    assert len(rollouts) == 2
    with h5py.File(rollouts[0].path, "r") as h5:
        assert list(h5[f"{rollouts[0].traj}/obs/sensor_data"]) == ["front_shift"]
    results = json.loads((layout.evaluation(TASK, "naive_dc") / "results.json").read_text())
    assert results["camera"] == "front_shift" and results["rollouts"]["count"] == 2
    assert all("labelled" in row for row in results["detectors"].values())

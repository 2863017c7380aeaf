"""Bad input is refused before any work starts: one line naming the problem, exit status 2, and
nothing on disk changed. Run in this process through `aed_eval.cli.main` (the console script's
entry point), so each case costs a parse, not an interpreter."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import pytest

from aed_eval import cli
from aed_eval.executors import execute

TASK = "PressButton"


def tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


@pytest.fixture
def workspace(tmp_path: Path) -> Path:
    """A runs folder, a plain file, and a results file and a shard json that are not objects."""
    (tmp_path / "runs").mkdir()
    (tmp_path / "a_file").write_text("mine")
    (tmp_path / "list.json").write_text("[1, 2]")
    (tmp_path / "collection").mkdir()
    (tmp_path / "collection" / "demo_env000_0000.json").write_text("[]")
    return tmp_path


CASES = {
    "rollout of no environment": (
        ["rollout", "--policy", "naive_dc", "--num-envs", "0"],
        "num_envs=0: must be >= 1",
    ),
    "policy lr nan": (["train-policy", "--policy", "naive_dc", "--lr", "nan"], "lr=nan"),
    "detector lr nan": (["train-detector", "--detector", "lstm_ed", "--lr", "nan"], "lr=nan"),
    "encoder lr nan": (["train-encoder", "--lr", "nan"], "lr=nan"),
    "localizer colour 1": (["train-localizer", "--colour", "1"], "colour=1.0"),
    "localizer without data": (["train-localizer"], "no such collection folder"),
    "monitor without demonstrations": (
        ["monitor", "--policy", "naive_dc", "--num-demos", "0"],
        "num_demos=0",
    ),
    "evaluate without demonstrations": (
        ["evaluate", "--policy", "naive_dc", "--num-demos", "0"],
        "num_demos=0",
    ),
    "evaluate without a policy": (["evaluate", "--policy", "naive_dc"], "no policy checkpoint"),
    "train without data": (["train-policy", "--policy", "naive_dc"], "no such collection folder"),
    "calibrate at alpha 2": (["calibrate", "--alphas", "2"], "alphas=(2.0,)"),
    "demo of an unknown detector": (["demo", "--detectors", "juggle"], "detectors=['juggle']"),
    "demo stage refused up front": (["demo", "--labelled", "-1"], "num_successes=-1"),
    "collect into a file": (
        ["collect", "--num-envs", "1", "--out", "{ws}/a_file"],
        "a_file: a file, not a folder",
    ),
    "train into a file": (
        ["train-policy", "--policy", "naive_dc", "--out", "{ws}/a_file"],
        "a_file: a file, not a folder",
    ),
    "results that are a list": (
        ["report", "--results", "{ws}/list.json"],
        "not an `aed evaluate` results file",
    ),
    "shard json that is a list": (["data-info", "{ws}/collection"], "not an AED trajectory json"),
}
TAKES_TASK = {"rollout", "train-policy", "train-detector", "train-encoder", "train-localizer",
              "monitor", "evaluate", "calibrate", "demo", "collect"}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_is_one_line_status_2_and_changes_nothing(case, workspace, caplog, monkeypatch):
    monkeypatch.chdir(workspace)  # default outputs (runs/...) would land here
    args, named = CASES[case]
    argv = [a.format(ws=workspace) for a in args]
    if argv[0] in TAKES_TASK:
        argv += ["--task", TASK]
    before = tree(workspace)
    with caplog.at_level(logging.ERROR, logger="aed"):
        status = cli.main(argv)
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert status == 2 and len(errors) == 1 and named in errors[0], errors
    assert "\n" not in errors[0]
    assert tree(workspace) == before and sorted(p.name for p in workspace.iterdir()) == [
        "a_file", "collection", "list.json", "runs"]  # fmt: skip
    assert not list((workspace / "runs").iterdir())


class RunnerThatCannotStart:
    def __init__(self, why: str):
        raise ValueError(why)


def test_a_runner_failing_at_start_up_in_a_pool_names_its_error():
    make_runner = functools.partial(RunnerThatCannotStart, "checkpoint.pt: not a policy")
    with pytest.raises(ValueError, match="checkpoint.pt: not a policy"):
        execute([1, 2], make_runner, on_done=lambda _: None, workers=2)


def test_json_files_that_are_not_objects_are_named(tmp_path):
    """A calibration, a manifest and a feature cache's meta that parse but are not objects."""
    import numpy as np

    from aed_eval.calibrate import read_calibration
    from aed_models.train.feature_cache import FeatureCache, FeatureCacheError
    from aed_tasks.trajectory import MANIFEST, CollectionError, EpisodeRef, read_manifest

    (tmp_path / "calibration.json").write_text("[]")
    with pytest.raises(ValueError, match="not an `aed calibrate` file"):
        read_calibration(tmp_path / "detector.pt", "0" * 64)
    (tmp_path / MANIFEST).write_text("[1]")
    with pytest.raises(CollectionError, match="not a JSON object"):
        read_manifest(tmp_path)
    cache = FeatureCache(tmp_path / "cache", "0" * 64, seed=0, num_demos=1)
    shard = tmp_path / "agent_success_env000_0000.h5"
    cache.dir.mkdir(parents=True)
    np.savez(cache.path_for(shard), meta=np.array("[]"))
    ref = EpisodeRef(shard, "traj_0", "agent_success", TASK, "base", 0, 5, 0, True)
    with pytest.raises(FeatureCacheError, match="its meta is not a JSON object"):
        cache.load(ref)

"""`aed rollout`: policy episodes in novel environments, stored, resumable, worker-independent."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from aed_eval.collect import CollectConfig, run_collection
from aed_eval.rollout import ROLE, RolloutConfig, run_rollouts, stored_rollouts
from aed_models.nn import VisualHeadConfig
from aed_models.policies import POLICIES, make_policy, save_policy
from aed_tasks import trajectory

from .test_collect import digest

AED = str(Path(sys.executable).with_name("aed"))
TASK = "PressButton"


@pytest.fixture(scope="module")
def setting(tmp_path_factory) -> dict:
    """A tiny untrained NaiveDC checkpoint and one novel demonstration of environment 0."""
    root = tmp_path_factory.mktemp("rollout")
    config = POLICIES.preset(
        "naive_dc",
        "mini",
        visual=VisualHeadConfig(arch="small_cnn", out_dim=16, width=4),
        localizer=None,
        subgoal_head="linear",  # the pointer head needs a localizer
    )
    checkpoint = root / "policy.pt"
    save_policy(checkpoint, make_policy("naive_dc", config).eval())
    demos = root / "demos"
    run_collection(
        CollectConfig.from_preset(
            task=TASK,
            split="novel",
            envs=(0,),
            num_demos=1,
            num_successes=0,
            num_failures=0,
            out=demos,
            progress=False,
        )
    )
    return {"checkpoint": checkpoint, "demos": demos, "root": root}


def config(setting: dict, out: Path, **kwargs) -> RolloutConfig:
    return RolloutConfig.from_preset(
        task=TASK,
        policy="naive_dc",
        checkpoint=setting["checkpoint"],
        demos=setting["demos"],
        out=out,
        envs=(0,),
        num_episodes=3,
        num_demos=1,
        shard_size=1,
        horizon=12,
        progress=False,
        **kwargs,
    )


@pytest.fixture(scope="module")
def uninterrupted(setting) -> Path:
    out = setting["root"] / "uninterrupted"
    summary = run_rollouts(config(setting, out))
    assert summary.episodes == 3 and summary.skipped == 0
    return out


@pytest.mark.slow
def test_rollouts_are_stored_with_their_policy(uninterrupted, setting):
    shards = trajectory.scan_collection(uninterrupted, check="full").shards
    assert len(shards) == 3
    for shard in shards:
        (entry,) = shard.body["episodes"]
        assert entry["role"] == ROLE and entry["policy"] == "naive_dc" and entry["split"] == "novel"
        assert len(entry["policy_sha256"]) == 64 and entry["labels_known"] is False
        with h5py.File(shard.h5_path, "r") as h5:
            rgb, depth = trajectory.read_frames(h5, "traj_0")
            assert rgb.shape == (13, 120, 160, 3) and depth.shape == (13, 120, 160, 1)
            assert h5["traj_0/actions"].shape == (12, 4) and h5["traj_0/stage"].shape == (12,)
    assert {ref.env_index for ref in stored_rollouts(uninterrupted, "naive_dc").refs} == {0}


@pytest.mark.slow
def test_killed_rollout_resumed_by_two_workers_ends_with_the_same_rollouts(
    uninterrupted, setting, tmp_path
):
    """Killed mid-run (one worker), resumed with `workers=2`: exactly the uninterrupted one-worker
    run's rollouts."""
    out = tmp_path / "interrupted"
    args = [
        AED,
        "rollout",
        "--task",
        TASK,
        "--policy",
        "naive_dc",
        "--checkpoint",
        str(setting["checkpoint"]),
        "--demos",
        str(setting["demos"]),
        "--out",
        str(out),
        "--envs",
        "0",
        "--num-episodes",
        "3",
        "--num-demos",
        "1",
        "--shard-size",
        "1",
        "--horizon",
        "12",
        "--no-progress",
    ]
    process = subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 240
        while not list(out.glob(f"{ROLE}_*.json")):
            assert process.poll() is None, (
                f"aed rollout ended before it could be killed: {process.stderr.read()}"
            )
            assert time.monotonic() < deadline, "aed rollout committed nothing in time"
            time.sleep(0.05)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    committed = len(list(out.glob(f"{ROLE}_*.json")))
    assert 1 <= committed < 3, f"the kill came after {committed} of 3 shards"

    summary = run_rollouts(config(setting, out, workers=2))
    assert summary.skipped == committed and summary.episodes == 3 - committed
    assert digest(out) == digest(uninterrupted)


def test_bad_input_is_named(setting, tmp_path):
    with pytest.raises(ValueError, match="unknown policy 'juggle'"):
        RolloutConfig.from_preset(task=TASK, policy="juggle", checkpoint=setting["checkpoint"])
    with pytest.raises(FileNotFoundError, match="no policy checkpoint"):
        run_rollouts(
            RolloutConfig.from_preset(task=TASK, policy="dct", checkpoint=tmp_path / "missing.pt")
        )
    with pytest.raises(trajectory.CollectionError, match="no such collection folder"):
        run_rollouts(
            RolloutConfig.from_preset(
                task=TASK,
                policy="naive_dc",
                checkpoint=setting["checkpoint"],
                demos=tmp_path / "nothing",
                out=tmp_path / "out",
                progress=False,
            )
        )
    with pytest.raises(ValueError, match="a policy checkpoint of 'naive_dc', expected 'dct'"):
        run_rollouts(
            RolloutConfig.from_preset(
                task=TASK,
                policy="dct",
                checkpoint=setting["checkpoint"],
                demos=setting["demos"],
                out=tmp_path / "dct",
                envs=(0,),
                progress=False,
            )
        )
    result = subprocess.run(
        [
            AED,
            "rollout",
            "--task",
            TASK,
            "--policy",
            "naive_dc",
            "--checkpoint",
            str(tmp_path / "missing.pt"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2 and "missing.pt" in result.stderr


def test_workers_share_the_cores(monkeypatch):
    from aed_eval.executors import worker_threads

    monkeypatch.delenv("AED_WORKER_THREADS", raising=False)
    assert worker_threads(2) == max(1, (os.cpu_count() or 1) // 2) and worker_threads(10**6) == 1
    monkeypatch.setenv("AED_WORKER_THREADS", "0")
    assert worker_threads(2) == 0  # the libraries' own defaults
    monkeypatch.setenv("AED_WORKER_THREADS", "many")
    with pytest.raises(ValueError, match="AED_WORKER_THREADS='many'"):
        worker_threads(2)


@pytest.mark.slow
def test_bench_workers_script_runs(setting, tmp_path):
    from tests.helpers import load_script

    bench = load_script("bench_workers")
    result = bench.main(
        bench.Config(
            demos=setting["demos"], envs=(0,), horizon=3, repeats=1, out=tmp_path / "bench.json"
        )
    )
    assert (
        len(result["seconds"]["share"]) == len(result["seconds"]["defaults"]) == 1
        and result["speedup"] > 0
    )

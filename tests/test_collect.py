"""`aed collect` end to end: labels on disk, ManiSkill's replay tool, resuming after a kill,
worker-count independence, and corrupt or foreign files reported by name."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from aed_eval.collect import CollectConfig, CollectError, check_retry_rate, retries, run_collection
from aed_eval.data_info import summarize
from aed_models.data import EnvironmentIterations, load_episodes
from aed_models.recipe import Composition
from aed_tasks import trajectory

AED = str(Path(sys.executable).with_name("aed"))
# Physics only (fast): two environments, two successes and two failures each, one episode a shard.
STATE_RUN = {
    "task": "PickPlace",
    "split": "base",
    "envs": (0, 1),
    "num_demos": 0,
    "num_successes": 2,
    "num_failures": 2,
    "num_explore": 0,
    "shard_size": 1,
    "obs_mode": "state",
    "progress": False,
}


def array_hashes(h5_path: Path) -> list[tuple[str, str]]:
    """(name, sha1 of its bytes) of every dataset of an h5 file."""
    hashes: list[tuple[str, str]] = []

    def visit(name: str, obj) -> None:
        if isinstance(obj, h5py.Dataset):
            hashes.append((name, hashlib.sha1(obj[()].tobytes()).hexdigest()))

    with h5py.File(h5_path, "r") as h5:
        h5.visititems(visit)
    return sorted(hashes)


def digest(root: Path) -> dict[str, tuple]:
    """What a collection holds, shard by shard: episode entries and hashes of every array."""
    return {
        shard.json_path.stem: (
            json.dumps(shard.body["episodes"], sort_keys=True),
            array_hashes(shard.h5_path),
        )
        for shard in trajectory.scan_collection(root, check="full")
    }


@pytest.fixture(scope="module")
def rgbd_collection(tmp_path_factory) -> Path:
    """Pick & Place base, environment 0: one demonstration, one success, two failures, RGB-D."""
    out = tmp_path_factory.mktemp("rgbd")
    cfg = CollectConfig.from_preset(
        task="PickPlace",
        split="base",
        envs=(0,),
        num_demos=1,
        num_successes=1,
        num_failures=2,
        num_explore=0,
        shard_size=2,
        out=out,
        progress=False,
    )
    summary = run_collection(cfg)
    assert summary.episodes == 4 and summary.skipped == 0
    return out


@pytest.fixture(scope="module")
def state_collection(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("uninterrupted")
    run_collection(CollectConfig.from_preset(**STATE_RUN, out=out))
    return out


@pytest.mark.slow
def test_episodes_on_disk_carry_roles_frames_and_labels(rgbd_collection):
    episodes = trajectory.scan_collection(rgbd_collection, check="full").episodes()
    assert sorted(e.role for e in episodes) == [
        "agent_failure",
        "agent_failure",
        "agent_success",
        "demo",
    ]
    kinds = {e.error_kind for e in episodes if e.role == "agent_failure"}
    assert len(kinds) == 2, "failures rotate through the error kinds"
    for ref in episodes:
        with h5py.File(ref.path, "r") as h5:
            group = h5[ref.traj]
            rgb, depth = trajectory.read_frames(h5, ref.traj)
            labels = group["error_label"][()]
            assert rgb.shape == (ref.num_frames, 120, 160, 3) and rgb.dtype == np.uint8
            assert depth.shape == (ref.num_frames, 120, 160, 1) and depth.dtype == np.int16
            assert group["actions"].shape == (ref.length, 4) and labels.dtype == np.uint8
            assert group["env_states/actors/vessel"].shape[0] == ref.num_frames
            assert rgb[0].std() > 10 and (depth > 0).mean() > 0.9
        if ref.role == "agent_failure":
            onset = ref.error_onset
            assert not ref.success and 0 < onset < ref.length
            assert not labels[:onset].any() and labels[onset:].all()
        else:
            assert ref.success and ref.error_onset is None and not labels.any()


@pytest.mark.slow
def test_training_batches_of_real_episodes_keep_labels_aligned(rgbd_collection):
    batch = EnvironmentIterations(
        load_episodes(rgbd_collection), "detector", max_frames=24, seed=0
    )[0]
    rollouts = batch["rollouts"]
    assert rollouts["frames"].shape[2:] == (4, 120, 160) and batch["demos"]["frames"].shape[0] == 5
    assert 0 < rollouts["frames"][:, :, 3].max() <= 1.0
    for i in range(len(rollouts["lengths"])):
        n = int(rollouts["lengths"][i])
        labels = rollouts["labels"][i, :n]
        if rollouts["is_failure"][i]:
            assert labels[0] == 0 and labels[-1] == 1 and torch.all(labels.diff() >= 0)
        else:
            assert not labels.any()


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["--use-env-states", "--no-use-env-states"])
def test_maniskill_replay_tool_reproduces_the_episodes(rgbd_collection, tmp_path, mode):
    """ManiSkill's replay reads our shards; replaying the actions alone reproduces each outcome."""
    for stem in ("agent_success_env000_0000", "agent_failure_env000_0000"):
        shard = tmp_path / f"{stem}.h5"
        for suffix in (".h5", ".json"):
            shutil.copy(rgbd_collection / f"{stem}{suffix}", shard.with_suffix(suffix))
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "mani_skill.trajectory.replay_trajectory",
                "--traj-path",
                str(shard),
                mode,
                "--obs-mode",
                "state",
                "--allow-failure",
                "--save-traj",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-4000:]
        replayed = next(tmp_path.glob(f"{stem}.state.*.h5"))
        with h5py.File(shard, "r") as original, h5py.File(replayed, "r") as copy:
            assert sorted(copy) == sorted(original)
            for traj in original:
                np.testing.assert_array_equal(
                    copy[f"{traj}/actions"][()], original[f"{traj}/actions"][()]
                )
                assert bool(copy[f"{traj}/success"][-1]) == bool(original[f"{traj}/success"][-1]), (
                    traj
                )


def test_data_info_counts_roles_and_kinds(rgbd_collection):
    info = summarize(rgbd_collection)
    assert info["episodes"] == 4 and info["by_role"] == {
        "agent_failure": 2,
        "agent_success": 1,
        "demo": 1,
    }
    assert sum(info["error_kinds"].values()) == 2 and info["bytes_per_frame"] > 0
    from aed_tasks.tasks.pick_place import PickPlaceEnv

    reached = info["stages_reached"]  # successes end in the last stage; failures never do
    assert sum(reached["success"].values()) == 2 and sum(reached["failure"].values()) == 2
    last = PickPlaceEnv.num_stages
    assert reached["success"] == {str(last): 2}
    assert all(int(stage) < last for stage in reached["failure"])
    result = subprocess.run(
        [AED, "data-info", str(rgbd_collection)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert "4 episodes" in result.stdout and "agent_failure 2" in result.stdout
    assert f"stage reached, success: 2 reached {PickPlaceEnv.num_stages}" in result.stdout


def test_exploration_episodes_move_the_arm_anywhere_and_only_the_encoder_reads_them(tmp_path):
    """`--num-explore`: the arm visits random points of the task's region, away from the task
    objects; the policies' and detectors' training draws leave these episodes out."""
    from aed_tasks.tasks.press_button import PressButtonEnv

    run = {**STATE_RUN, "task": "PressButton", "envs": (0,), "num_demos": 1, "num_successes": 1}
    run.update(num_failures=0, num_explore=2, obs_mode="rgbd", out=tmp_path)
    cfg = CollectConfig.from_preset(**run)
    run_collection(cfg)
    episodes = load_episodes(tmp_path)
    explore = [e for e in episodes if e.role == "explore"]
    assert len(explore) == 2 and summarize(tmp_path)["by_role"]["explore"] == 2
    x0, x1, y0, y1, z0, z1 = PressButtonEnv.explore_region
    for ref in explore:
        with h5py.File(ref.path, "r") as h5:
            tcp = h5[ref.traj]["obs/extra/tcp_pose"][()][:, :3]
            button = h5[ref.traj]["env_states/articulations/button"][0, :3]
        travelled = np.linalg.norm(np.diff(tcp, axis=0), axis=1).sum()
        assert ref.length >= 10 and travelled > 0.2, (ref.length, travelled)
        assert (tcp[-1, :2] >= [x0 - 0.02, y0 - 0.02]).all()
        assert (tcp[-1, :2] <= [x1 + 0.02, y1 + 0.02]).all()
        assert np.linalg.norm(tcp[-1] - button) > 0.01  # it went somewhere, not to the button
    drawn = EnvironmentIterations(episodes, Composition(1, 1), seed=0)[0]
    assert drawn["rollouts"]["lengths"].tolist() == [
        e.num_frames for e in episodes if e.role == "agent_success"
    ]


@pytest.mark.slow
def test_killed_collection_resumed_by_two_workers_ends_with_the_same_episodes(
    state_collection, tmp_path
):
    """Killed mid-run (one worker), resumed with `workers=2`: exactly the uninterrupted one-worker
    run's episodes (a resume and a worker count that change nothing)."""
    out = tmp_path / "interrupted"
    args = [
        AED,
        "collect",
        "--task",
        "PickPlace",
        "--split",
        "base",
        "--envs",
        "0",
        "1",
        "--num-demos",
        "0",
        "--num-successes",
        "2",
        "--num-failures",
        "2",
        "--num-explore",
        "0",
        "--shard-size",
        "1",
        "--obs-mode",
        "state",
        "--no-progress",
        "--out",
        str(out),
    ]
    process = subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 240
        while len(list(out.glob("agent_*.json"))) < 2:  # at least two shards committed
            assert process.poll() is None, "aed collect ended before it could be killed"
            assert time.monotonic() < deadline, "aed collect committed nothing in time"
            time.sleep(0.05)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    committed = len(list(out.glob("agent_*.json")))
    assert 2 <= committed < 8, f"the kill came after {committed} of 8 shards"
    (out / "agent_success_env001_0001.h5.tmp").write_bytes(
        b"half a shard"
    )  # as a kill mid-write leaves
    (out / "agent_failure_env001_0001.h5").write_bytes(
        b"renamed, json never written"
    )  # a kill before the commit

    summary = run_collection(CollectConfig.from_preset(**{**STATE_RUN, "workers": 2}, out=out))
    assert summary.skipped == committed and summary.episodes == 8 - committed
    assert not list(out.glob("*.tmp"))
    assert digest(out) == digest(state_collection)


@pytest.mark.slow
def test_killed_rgbd_collection_resumed_by_two_workers_ends_with_the_same_frames(
    rgbd_collection, tmp_path
):
    """The same on rendered frames: every RGB-D array of the run killed, then resumed by
    spawned workers, equals the uninterrupted one-worker run's."""
    out = tmp_path / "interrupted"
    args = [
        AED,
        "collect",
        "--task",
        "PickPlace",
        "--split",
        "base",
        "--envs",
        "0",
        "--num-demos",
        "1",
        "--num-successes",
        "1",
        "--num-failures",
        "2",
        "--num-explore",
        "0",
        "--shard-size",
        "2",
        "--no-progress",
        "--out",
        str(out),
    ]
    process = subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 300
        while (
            not list(out.glob("*.json")) or len(list(out.glob("*.json"))) < 2
        ):  # the manifest and a shard
            assert process.poll() is None, "aed collect ended before it could be killed"
            assert time.monotonic() < deadline, "aed collect committed nothing in time"
            time.sleep(0.05)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    run_collection(
        CollectConfig.from_preset(
            task="PickPlace",
            split="base",
            envs=(0,),
            num_demos=1,
            num_successes=1,
            num_failures=2,
            num_explore=0,
            shard_size=2,
            out=out,
            workers=2,
            progress=False,
        )
    )
    resumed, original = digest(out), digest(rgbd_collection)
    assert resumed == original
    assert any(
        "obs/sensor_data/front/rgb" in name for _, hashes in resumed.values() for name, _ in hashes
    )


@pytest.mark.slow
def test_ray_executor_gives_the_same_episodes(state_collection, tmp_path):
    ray = pytest.importorskip(
        "ray", reason="ray is not installed: the dev extra brings it (`make setup`)"
    )
    try:
        run_collection(
            CollectConfig.from_preset(
                **{**STATE_RUN, "executor": "ray", "workers": 2}, out=tmp_path
            )
        )
    finally:
        ray.shutdown()
    assert digest(tmp_path) == digest(state_collection)


def test_rerun_of_a_finished_collection_records_nothing(state_collection):
    before = digest(state_collection)
    summary = run_collection(CollectConfig.from_preset(**STATE_RUN, out=state_collection))
    assert summary.episodes == 0 and summary.skipped == 8
    assert digest(state_collection) == before


@pytest.mark.parametrize(
    "damage", ["json_garbage", "h5_truncated", "h5_same_size", "foreign_file", "other_settings"]
)
def test_corrupt_or_foreign_files_are_named_and_nothing_is_lost(state_collection, tmp_path, damage):
    root = tmp_path / "copy"
    shutil.copytree(state_collection, root)
    victim = root / "agent_failure_env000_0000"
    if damage == "json_garbage":
        victim.with_suffix(".json").write_text('{"env_info": ')
        named = victim.with_suffix(".json").name
    elif damage == "h5_truncated":
        data = victim.with_suffix(".h5").read_bytes()
        victim.with_suffix(".h5").write_bytes(data[: len(data) // 2])
        named = victim.with_suffix(".h5").name
    elif damage == "h5_same_size":  # size unchanged: only the sha256 tells
        data = bytearray(victim.with_suffix(".h5").read_bytes())
        data[len(data) // 2] ^= 0xFF
        victim.with_suffix(".h5").write_bytes(bytes(data))
        named = victim.with_suffix(".h5").name
    elif damage == "foreign_file":
        (root / "notes.txt").write_text("not a shard")
        named = "notes.txt"
    else:
        named = trajectory.MANIFEST
    files = {p.name: p.read_bytes() for p in root.iterdir()}
    cfg = CollectConfig.from_preset(
        **{**STATE_RUN, "shard_size": 2} if damage == "other_settings" else STATE_RUN, out=root
    )
    with pytest.raises(trajectory.CollectionError, match=named.replace(".", r"\.")):
        run_collection(cfg)
    assert {p.name: p.read_bytes() for p in root.iterdir()} == files, (
        "a failed run changed the folder"
    )


def test_retries_are_counted_shown_and_fail_loudly(state_collection, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(state_collection, root)
    assert summarize(root)["retries"]["rejected"] == retries(root)[1]
    shard = root / "agent_failure_env000_0000.json"  # retries live in the json: the h5's hash holds
    body = json.loads(shard.read_text())
    body["episodes"][0].update(
        attempt=3, rejected=["not a 'no_grasp' failure: the mug moved 4 cm"] * 3
    )
    shard.write_text(json.dumps(body))
    info = summarize(root)
    assert info["retries"]["rejected"] == 3 + retries(state_collection)[1]
    assert "the mug moved 4 cm" in next(iter(info["retries"]["problems"]))
    with pytest.raises(
        CollectError, match=r"rejected tries for 8 episodes .* > max_retry_rate=20%"
    ):
        check_retry_rate(root, 0.2)
    check_retry_rate(root, 1.0)


def test_config_errors_name_the_field():
    with pytest.raises(ValueError, match="task='Juggle'"):
        CollectConfig.from_preset(task="Juggle")
    with pytest.raises(ValueError, match=r"envs=\(99,\)"):
        CollectConfig.from_preset(task="PickPlace", envs=(99,))
    with pytest.raises(ValueError, match="workers=0"):
        CollectConfig.from_preset(task="PickPlace", workers=0)

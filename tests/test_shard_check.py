"""Readers verify what they read: each shard's sha256 once per process and file version, so
that damage of the same size is named (one line, the file) before anything uses it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from aed_models.data import load_episodes
from aed_tasks import trajectory
from tests.test_data import synthetic

AED = str(Path(sys.executable).with_name("aed"))
STEMS = [f"{role}_env{e:03d}_0000" for e in (0, 1) for role in ("demo", "agent_success")]


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    """Two environments, each with 2 demonstrations and 2 successes (synthetic frames)."""
    root = tmp_path_factory.mktemp("pristine")
    info = {"env_id": "aed_tasks:AED-PickPlace-base", "env_kwargs": {}, "max_episode_steps": 250}
    for stem in STEMS:
        role, env = stem.rsplit("_env", 1)[0], int(stem.split("_env")[1][:3])
        writer = trajectory.ShardWriter(root / f"{stem}.h5")
        for k in range(2):
            writer.add(*synthetic(role, env, seed=10 * env + k, steps=8 + k))
        writer.commit(info, {"env_index": env, "group": role})
    return root


@pytest.fixture
def collection(pristine, tmp_path) -> Path:
    """A fresh copy (new files: never verified in this process)."""
    return Path(shutil.copytree(pristine, tmp_path / "collection"))


def damage(h5: Path) -> None:
    """Flip one byte in the middle of the file: same size, another sha256."""
    data = bytearray(h5.read_bytes())
    data[len(data) // 2] ^= 0xFF
    h5.write_bytes(bytes(data))


@pytest.fixture
def hashes(monkeypatch) -> list[str]:
    """The names of the files whose sha256 is computed from now on."""
    seen: list[str] = []
    original = trajectory.sha256

    def counting(path: Path) -> str:
        seen.append(Path(path).name)
        return original(path)

    monkeypatch.setattr(trajectory, "sha256", counting)
    return seen


def test_same_size_damage_is_named_by_the_readers(collection):
    h5 = collection / "agent_success_env001_0000.h5"
    damage(h5)
    assert len(trajectory.scan_collection(collection, check="size").episodes()) == 8  # unseen
    for read in (trajectory.scan_collection, load_episodes):
        with pytest.raises(trajectory.CollectionError, match="sha256 differs") as error:
            read(collection)
        assert error.value.path == h5


def test_each_file_version_is_hashed_once_per_process(collection, hashes):
    trajectory.scan_collection(collection)
    assert sorted(hashes) == sorted(f"{stem}.h5" for stem in STEMS)
    hashes.clear()
    load_episodes(collection)  # training, rollout, calibrate and evaluate read this way
    assert hashes == []
    h5 = collection / "demo_env000_0000.h5"
    stat = h5.stat()
    os.utime(h5, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))  # another version of that file
    trajectory.scan_collection(collection)
    assert hashes == [h5.name]
    hashes.clear()
    trajectory.scan_collection(collection, check="full")  # before a collection is written to
    assert len(hashes) == len(STEMS)


def test_damage_after_a_verified_read_is_named_at_the_next_read(collection):
    trajectory.scan_collection(collection)
    h5 = collection / "demo_env001_0000.h5"
    damage(h5)  # a write: new mtime, so the verification is not reused
    with pytest.raises(trajectory.CollectionError, match=h5.name):
        trajectory.scan_collection(collection)


def test_what_a_writer_commits_counts_as_verified(tmp_path, hashes):
    writer = trajectory.ShardWriter(tmp_path / "agent_success_env000_0000.h5")
    writer.add(*synthetic("agent_success", 0, seed=0, steps=4))
    writer.commit({"env_id": "aed_tasks:AED-PickPlace-base", "env_kwargs": {}})
    hashes.clear()
    trajectory.scan_collection(tmp_path)
    assert hashes == []


def test_training_on_a_damaged_shard_is_one_line_and_status_2(collection, tmp_path):
    h5 = collection / "agent_success_env000_0000.h5"
    damage(h5)
    result = subprocess.run(
        [
            AED,
            "train-policy",
            "--task",
            "PickPlace",
            "--data",
            str(collection),
            "--out",
            str(tmp_path / "policy"),
            "--epochs",
            "1",
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(h5) in lines[0] and "sha256 differs" in lines[0], lines
    assert not (tmp_path / "policy" / "last.pt").exists()


def test_bench_shard_check_script_runs(tmp_path):
    from tests.helpers import load_script

    bench = load_script("bench_shard_check")
    cfg = bench.Config(episodes=3, steps=4, shard_size=2, runs=1, scratch=tmp_path)
    cfg.out = tmp_path / "bench.json"
    result = bench.main(cfg)
    assert (result["episodes"], result["shards"]) == (3, 2) and cfg.out.exists()
    assert set(result["median_s"]) == {"size", "quick_first", "quick_again", "full"}
    assert list(tmp_path.iterdir()) == [cfg.out]  # the synthetic collection is gone

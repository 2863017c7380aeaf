"""One writer per output folder (`aed_tasks.locks`): a second writer is refused in one line
naming the holder's pid and changes nothing; a lock of a dead process is taken over; pool
workers die with their parent, so that no orphan keeps committing shards."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from aed_eval.producer import produce
from aed_tasks import locks, trajectory
from aed_tasks.locks import LOCK_NAME, FolderLock, FolderLockedError, folder_lock, lock_holder
from tests.helpers import write_synthetic_collection
from tests.test_data import synthetic
from tests.test_producer import FakeConfig, FakeRunner, FakeShard

AED = str(Path(sys.executable).with_name("aed"))
# A process that takes a folder's lock and keeps it; the module is loaded by path (no aed_tasks
# import: it would load ManiSkill, seconds).
HOLDER = """
import importlib.util, sys, time
spec = importlib.util.spec_from_file_location("locks", sys.argv[1])
locks = importlib.util.module_from_spec(spec)
spec.loader.exec_module(locks)
locks.FolderLock(sys.argv[2]).acquire()
print("held", flush=True)
time.sleep(600)
"""


@contextmanager
def holder(folder: Path) -> Iterator[subprocess.Popen]:
    """Another process holding `folder`'s lock for the block."""
    process = subprocess.Popen(
        [sys.executable, "-c", HOLDER, locks.__file__, str(folder)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout.readline().strip() == "held"
        yield process
    finally:
        process.kill()
        process.wait()


def dead_pid() -> int:
    """The pid of a process that has ended."""
    process = subprocess.Popen(["true"])
    process.wait()
    return process.pid


def snapshot(root: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under `root`: its bytes and mtime."""
    return {
        str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(autouse=True)
def env_info(monkeypatch):
    monkeypatch.setattr(
        trajectory, "env_info", lambda env: {"env_id": "AED-PickPlace-base", "env_kwargs": {}}
    )
    FakeRunner.made = []


def test_a_second_writer_is_refused_naming_the_holder(tmp_path):
    with holder(tmp_path / "out") as process:
        assert lock_holder(tmp_path / "out") == process.pid
        with pytest.raises(FolderLockedError, match=f"another run \\(pid {process.pid}\\)"):
            FolderLock(tmp_path / "out").acquire()
    with folder_lock(tmp_path / "out") as lock:  # the holder was killed: free again
        assert lock_holder(tmp_path / "out") == os.getpid()
        with pytest.raises(FolderLockedError, match=f"pid {os.getpid()}"):  # even in-process
            FolderLock(tmp_path / "out").acquire()
    assert not lock.path.exists()  # released: the folder holds no lock file


def test_a_lock_left_by_a_killed_process_is_taken_over_with_a_warning(tmp_path, caplog):
    with holder(tmp_path) as process:
        process.send_signal(signal.SIGKILL)
        process.wait()
        assert lock_holder(tmp_path) == process.pid  # the file stays; the kernel's lock does not
        with caplog.at_level(logging.WARNING, logger="aed_tasks.locks"):
            with folder_lock(tmp_path):
                assert lock_holder(tmp_path) == os.getpid()
    assert f"stale lock left by pid {process.pid} (no longer running)" in caplog.text


def test_without_flock_the_holders_pid_decides(tmp_path, monkeypatch, caplog):
    def no_flock(fd: int, op: int) -> None:
        raise OSError(37, "No locks available")  # ENOLCK, as on some network filesystems

    monkeypatch.setattr(locks.fcntl, "flock", no_flock)
    with holder(tmp_path / "live") as process:  # the holder took its lock before the patch
        with pytest.raises(FolderLockedError, match=f"pid {process.pid}"):
            FolderLock(tmp_path / "live").acquire()
    (tmp_path / LOCK_NAME).write_text(f"{dead_pid()}\n")
    with caplog.at_level(logging.WARNING, logger="aed_tasks.locks"):
        with folder_lock(tmp_path):
            pass
    assert "no longer running" in caplog.text


def test_a_refused_production_changes_nothing_on_disk(tmp_path):
    """Two producers over one folder: the second is refused before it reads, writes or
    deletes anything (not even a leftover of the first)."""
    produce(FakeConfig(tmp_path), [FakeShard(0, 0, 1)], FakeRunner, "fake")
    (tmp_path / "agent_success_env001_0000.h5.tmp").write_bytes(b"the first run's shard")
    with holder(tmp_path) as process:
        before = snapshot(tmp_path)
        with pytest.raises(FolderLockedError, match=f"pid {process.pid}"):
            produce(
                FakeConfig(tmp_path), [FakeShard(0, 0, 1), FakeShard(1, 0, 1)], FakeRunner, "fake"
            )
        assert snapshot(tmp_path) == before
    assert FakeRunner.made == [(0, 0)]


def test_a_collection_being_written_reads_as_such(tmp_path, caplog):
    """The lock file is no foreign file, and a live writer's temporaries are no leftovers."""
    writer = trajectory.ShardWriter(tmp_path / "agent_success_env000_0000.h5")
    writer.add(*synthetic("agent_success", 0, seed=0, steps=4))
    writer.commit({"env_id": "aed_tasks:AED-PickPlace-base", "env_kwargs": {}})
    (tmp_path / "agent_success_env001_0000.h5.tmp").write_bytes(b"in progress")
    with caplog.at_level(logging.INFO, logger="aed_tasks.trajectory"):
        with holder(tmp_path) as process:
            assert len(trajectory.scan_collection(tmp_path).episodes()) == 1
        assert f"being written by pid {process.pid}: 1 unfinished" in caplog.text
        assert "interrupted" not in caplog.text
        trajectory.scan_collection(tmp_path)  # its writer is gone: a leftover now
    assert "1 leftover(s) of an interrupted collection" in caplog.text


@pytest.fixture(scope="module")
def synthetic_collection(tmp_path_factory) -> Path:
    """Two environments, each with 2 demos, 2 successes and 2 failures (synthetic frames)."""
    counts = {"demo": 2, "agent_success": 2, "agent_failure": 2}
    return write_synthetic_collection(tmp_path_factory.mktemp("collection"), counts)


@pytest.mark.parametrize(
    "command",
    [
        ["collect", "--task", "PickPlace", "--envs", "0", "--obs-mode", "state"],
        ["train-policy", "--task", "PickPlace", "--epochs", "1"],
        ["train-detector", "--task", "PickPlace", "--detector", "lstm_ed", "--epochs", "1"],
    ],
    ids=lambda c: c[0],
)
def test_a_command_writing_into_a_held_folder_is_one_line_and_status_2(
    command, synthetic_collection, tmp_path
):
    out = tmp_path / "out"
    out.mkdir()
    (out / "last.pt").write_bytes(b"the holder's checkpoint")
    with holder(out) as process:
        before = snapshot(out)
        args = [AED, *command, "--out", str(out), "--no-progress"]
        if command[0] != "collect":
            args += ["--data", str(synthetic_collection), "--num-envs", "2"]
        result = subprocess.run(args, capture_output=True, text=True, timeout=300)
        assert snapshot(out) == before
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"another run (pid {process.pid}) is writing here" in lines[0]
    assert str(out) in lines[0]


def children(pid: int) -> set[int]:
    """The pids of the live processes whose parent is `pid`."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.add(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
def test_a_killed_collection_takes_its_workers_along_and_its_lock_is_taken_over(tmp_path, caplog):
    """`aed collect --workers 2`: a second collection into its folder is refused naming it;
    `kill -9` of the parent alone ends both workers (no orphan commits another shard), and
    the lock it left is taken over."""
    out = tmp_path / "out"
    args = [
        AED,
        "collect",
        "--task",
        "PickPlace",
        "--num-envs",
        "8",
        "--num-demos",
        "0",
        "--num-successes",
        "10",  # 80 shards: far more work than the test waits for (it is killed)
        "--num-failures",
        "0",
        "--shard-size",
        "1",
        "--obs-mode",
        "state",
        "--workers",
        "2",
        "--no-progress",
        "--out",
        str(out),
    ]
    first = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 240
        while len(list(out.glob("*.h5.tmp"))) < 2:  # both workers are writing a shard
            assert first.poll() is None, "aed collect ended before it could be killed"
            assert time.monotonic() < deadline, "the workers wrote nothing in time"
            time.sleep(0.05)
        second = subprocess.run(args, capture_output=True, text=True, timeout=300)
        assert second.returncode == 2, second.stderr
        assert len(second.stderr.strip().splitlines()) == 1
        assert f"another run (pid {first.pid}) is writing here" in second.stderr
        assert first.poll() is None, "the first collection ended before the refusal was checked"
        workers = children(first.pid)
        assert len(workers) >= 2, workers
    finally:
        first.send_signal(signal.SIGKILL)  # the parent only, not its process group
        first.wait()
    committed = sorted(p.name for p in out.glob("*.json"))
    try:
        deadline = time.monotonic() + 10
        while any(alive(pid) for pid in workers):
            assert time.monotonic() < deadline, f"orphans: {[p for p in workers if alive(p)]}"
            time.sleep(0.1)
    finally:  # leave no orphan behind, whatever happened
        for pid in filter(alive, workers):
            os.kill(pid, signal.SIGKILL)
    time.sleep(1)
    assert sorted(p.name for p in out.glob("*.json")) == committed  # no orphan committed
    assert lock_holder(out) == first.pid
    with caplog.at_level(logging.WARNING, logger="aed_tasks.locks"):
        with folder_lock(out):
            pass
    assert f"stale lock left by pid {first.pid}" in caplog.text

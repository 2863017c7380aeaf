"""`aed train-encoder`, `aed train-localizer`, `aed train-policy` and `aed train-detector` as
commands: a `kill -9`
mid-run, resumed, ends with the weights of an uninterrupted run; a crafted pickle is refused
without running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from aed_models.checkpoint import FORMAT, CheckpointError, load_checkpoint
from tests.helpers import write_synthetic_collection

AED = str(Path(sys.executable).with_name("aed"))
# Tiny runs of the mini models on synthetic episodes of 2 environments: 1 episode of each role
# an iteration, 2 frames of each. The mini policies read a frozen scene encoder and a target
# localizer.
TRAININGS = {
    "policy": (
        ["train-policy", "--policy", "naive_dc", "--composition", "1", "1", "--epochs", "20"],
        "policy.pt",
    ),
    "detector": (
        ["train-detector", "--detector", "lstm_ed", "--composition", "1", "1", "1"]
        + ["--epochs", "4"],
        "detector.pt",
    ),
}


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> Path:
    """Pick & Place: per environment 2 demos, 2 successes, 2 failures."""
    counts = {"demo": 2, "agent_success": 2, "agent_failure": 2}
    return write_synthetic_collection(tmp_path_factory.mktemp("collection"), counts)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> Path:
    """Press Button with env states (what the scene encoder learns), stages and a camera (what
    the localizer matches): per environment 2 demos and 2 successes."""
    from tests.models.test_localizer import synthetic

    return write_synthetic_collection(
        tmp_path_factory.mktemp("scenes"),
        {"demo": 2, "agent_success": 2},
        steps=6,
        make_episode=synthetic,
        demo_seed_offset=10,
    )


@pytest.fixture(scope="module")
def encoder(scenes, tmp_path_factory) -> Path:
    """`aed train-encoder` for one epoch: the frozen head of the mini policies."""
    out = tmp_path_factory.mktemp("encoder")
    args = ["--task", "PressButton", "--data", str(scenes), "--num-envs", "0", "--epochs", "1"]
    result = subprocess.run(
        [AED, "train-encoder", *args, "--no-progress", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    return out / "encoder.pt"


@pytest.fixture(scope="module")
def localizer(scenes, tmp_path_factory) -> Path:
    """`aed train-localizer` for one epoch of a few updates."""
    out = tmp_path_factory.mktemp("localizer")
    args = ["--task", "PressButton", "--data", str(scenes), "--num-envs", "0", "--epochs", "1"]
    result = subprocess.run(
        [AED, "train-localizer", *args, "--updates", "3", "--batch", "4", "--no-progress"]
        + ["--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    return out / "localizer.pt"


@pytest.fixture
def command(request, collection) -> Callable[[str, Path], list[str]]:
    """The command line of a tiny training (`which`) into `out`."""

    def build(which: str, out: Path) -> list[str]:
        args, _ = TRAININGS[which]
        if which == "policy":
            encoder = request.getfixturevalue("encoder")
            data = [
                "--task",
                "PressButton",
                "--data",
                str(request.getfixturevalue("scenes")),
                "--encoder",
                str(encoder),
                "--localizer",
                str(request.getfixturevalue("localizer")),
            ]
        else:
            data = ["--task", "PickPlace", "--data", str(collection)]
        return [
            AED,
            *args,
            *data,
            "--num-envs",
            "2",
            "--max-frames",
            "2",
            "--no-progress",
            "--out",
            str(out),
        ]

    return build


def kill_after_first_checkpoint(args: list[str], out: Path) -> int:
    """Run `args`, `kill -9` it (its whole process group) once `<out>/last.pt` exists;
    returns the epoch that checkpoint holds."""
    process = subprocess.Popen(
        args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 300
        while not (out / "last.pt").exists():
            assert process.poll() is None, f"ended before its kill: {process.stderr.read()}"
            assert time.monotonic() < deadline, "no checkpoint in time"
            time.sleep(0.02)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    return torch.load(out / "last.pt", weights_only=True)["extra"]["epoch"]


@pytest.mark.slow
@pytest.mark.parametrize("which", sorted(TRAININGS))
def test_a_training_killed_mid_run_resumes_to_the_uninterrupted_weights(which, command, tmp_path):
    _, final = TRAININGS[which]
    reference = subprocess.Popen(  # runs beside the interrupted one
        command(which, tmp_path / "uninterrupted"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    out = tmp_path / "interrupted"
    epochs = int(TRAININGS[which][0][-1])
    epoch = kill_after_first_checkpoint(command(which, out), out)
    assert 1 <= epoch < epochs and not (out / final).exists(), f"killed after epoch {epoch}"
    assert (out / ".aed.lock").exists()  # left by the killed run, taken over by the next
    resumed = subprocess.run(command(which, out), capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert f"resumed from {out / 'last.pt'} after epoch" in resumed.stderr
    assert "taking over a stale lock" in resumed.stderr
    assert reference.wait(timeout=600) == 0, reference.stderr.read()
    got = torch.load(out / final, weights_only=True)
    want = torch.load(tmp_path / "uninterrupted" / final, weights_only=True)
    assert got["state_dict"].keys() == want["state_dict"].keys()
    for key, value in want["state_dict"].items():
        assert torch.equal(got["state_dict"][key], value), key
    assert [e["loss"] for e in got["extra"]["log"]] == [e["loss"] for e in want["extra"]["log"]]
    assert not (out / ".aed.lock").exists()


def crafted_checkpoint(path: Path, marker: Path) -> None:
    """An AED-looking checkpoint whose unpickling would run a shell command."""

    class Exploit:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    torch.save(
        {
            "format": FORMAT,
            "family": "policy",
            "name": "naive_dc",
            "config": {},
            "state_dict": {"w": Exploit()},
            "extra": {},
        },
        path,
    )


def test_a_crafted_pickle_is_refused_without_running(tmp_path):
    path, marker = tmp_path / "policy.pt", tmp_path / "pwned"
    crafted_checkpoint(path, marker)
    with pytest.raises(CheckpointError, match="refused: .* could run code .*posix.system") as e:
        load_checkpoint(path, family="policy")
    assert "\n" not in str(e.value) and "weights_only" not in str(e.value)
    assert not marker.exists()


def test_resuming_from_a_crafted_pickle_is_one_line_and_status_2(command, tmp_path):
    out, marker = tmp_path / "policy", tmp_path / "pwned"
    out.mkdir()
    crafted_checkpoint(out / "last.pt", marker)
    result = subprocess.run(command("policy", out), capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if not line.startswith("INFO ")]
    assert len(errors) == 1 and f"{out / 'last.pt'}: refused: it holds objects" in errors[0]
    assert not marker.exists() and not (out / "policy.pt").exists()


def test_a_policy_checkpoint_says_what_it_trained_on(command, tmp_path):
    """`training_summary`, the policy tables' columns: data per environment, epochs, cost."""
    from aed_models.checkpoint import load_checkpoint
    from aed_models.train.policy import training_summary

    out = tmp_path / "policy"
    args = [*command("policy", out), "--epochs", "2"]
    result = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    summary = training_summary(out / "policy.pt")
    assert summary["policy"] == "naive_dc" and summary["train_envs"] == 2
    assert summary["demos_per_env"] == 2 and summary["successes_per_env"] == [2]
    assert summary["epochs"] == 2 and summary["updates"] == 4
    # the cost is the epochs' own seconds (how many depends on the machine, so not asserted)
    log = load_checkpoint(out / "policy.pt", family="policy").extra["log"]
    assert summary["train_seconds"] == round(sum(e["seconds"] for e in log), 1) >= 0
    assert all(e["seconds"] >= 0 for e in log)
    assert summary["action_chunk"] == 1
    assert summary["own_pos_mse_last"] == summary["pos_mse_last"] > 0

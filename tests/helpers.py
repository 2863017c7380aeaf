"""Helpers shared by test modules."""

from __future__ import annotations

import importlib.util
import logging
import sys
from pathlib import Path
from types import ModuleType
from typing import Any


def load_script(name: str) -> ModuleType:
    """A module of scripts/ (not a package), imported by path."""
    path = Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def write_synthetic_collection(
    root: Path, counts: dict[str, int], envs: tuple[int, ...] = (0, 1), steps: int = 12
) -> Path:
    """A collection of `tests.test_data.synthetic` episodes: per environment, one shard per role
    with `counts[role]` episodes of `steps`, `steps + 2`, ... steps (no simulation)."""
    from aed_tasks import trajectory
    from tests.test_data import synthetic

    root.mkdir(parents=True, exist_ok=True)
    info = {"env_id": "aed_tasks:AED-PickPlace-base", "env_kwargs": {}, "max_episode_steps": 250}
    for env_index in envs:
        for role, n in counts.items():
            writer = trajectory.ShardWriter(root / f"{role}_env{env_index:03d}_0000.h5")
            for k in range(n):
                episode = synthetic(role, env_index, seed=100 * env_index + k, steps=steps + 2 * k)
                writer.add(*episode)
            writer.commit(info, {"env_index": env_index, "group": role})
    return root


def aed(argv: list[str], caplog: Any, capsys: Any) -> tuple[int, list[str], str]:
    """`aed <argv>` run in this process through the console script's `main`: its exit status,
    the error lines it logged and its stdout. A parse, not an interpreter start (see
    tests/test_cli.py and the kill tests for the console script itself)."""
    from aed_eval import cli

    caplog.clear()
    capsys.readouterr()
    with caplog.at_level(logging.ERROR, logger="aed"):
        status = cli.main(argv)
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    return status, errors, capsys.readouterr().out

"""The episode producer shared by `aed collect` and `aed rollout`, driven by a synthetic actor:
it records, resumes, refuses a plan that names a shard twice, and leaves the folder untouched
when it refuses."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import pytest

from aed_eval.producer import EpisodeRunner, produce
from aed_tasks import trajectory
from tests.test_data import synthetic


@dataclass(frozen=True)
class FakeShard:
    env_index: int
    start: int
    count: int

    @property
    def stem(self) -> str:
        return f"agent_success_env{self.env_index:03d}_{self.start:04d}"

    def indices(self) -> range:
        return range(self.start, self.start + self.count)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class FakeConfig:
    out: Path
    tag: str = "a"
    workers: int = 1
    executor: str = "local"
    ray_address: str | None = None
    progress: bool = False

    def identity(self) -> dict[str, Any]:
        return {"tag": self.tag}

    def to_dict(self) -> dict[str, Any]:
        return {"tag": self.tag, "out": str(self.out)}


class FakeRunner(EpisodeRunner):
    """Synthetic agent successes; counts the episodes it made."""

    made: list[tuple[int, int]] = []

    def env(self, shard: FakeShard) -> Any:
        class Env:  # what trajectory.env_info reads
            spec = None
            unwrapped = None

        return Env()

    def episode(self, shard: FakeShard, k: int) -> tuple[Any, Any, dict[str, Any]]:
        FakeRunner.made.append((shard.env_index, k))
        episode, steps = synthetic("agent_success", shard.env_index, seed=k, steps=6)
        return episode, steps, {"index": k}


@pytest.fixture(autouse=True)
def env_info(monkeypatch):
    monkeypatch.setattr(
        trajectory, "env_info", lambda env: {"env_id": "AED-PickPlace-base", "env_kwargs": {}}
    )
    FakeRunner.made = []


def test_records_then_resumes_only_what_is_missing(tmp_path):
    cfg = FakeConfig(tmp_path)
    first = produce(cfg, [FakeShard(0, 0, 2)], FakeRunner, "fake")
    assert (first.planned, first.skipped, first.episodes, first.successes) == (1, 0, 2, 2)
    again = produce(cfg, [FakeShard(0, 0, 2), FakeShard(1, 0, 1)], FakeRunner, "fake")
    assert (again.planned, again.skipped, again.episodes) == (2, 1, 1)
    assert FakeRunner.made == [(0, 0), (0, 1), (1, 0)]
    assert len(trajectory.scan_collection(tmp_path, check="full").episodes()) == 3


def test_a_shard_named_twice_is_refused_before_anything_is_written(tmp_path):
    with pytest.raises(ValueError, match="more than once"):
        produce(
            FakeConfig(tmp_path / "new"),
            [FakeShard(0, 0, 1), FakeShard(0, 0, 1)],
            FakeRunner,
            "fake",
        )
    assert not (tmp_path / "new").exists() and FakeRunner.made == []


def test_a_refused_run_leaves_the_manifest_and_shards_as_they_were(tmp_path):
    produce(FakeConfig(tmp_path), [FakeShard(0, 0, 2)], FakeRunner, "fake")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(trajectory.CollectionError, match="tag='a', this run asks 'b'"):
        produce(FakeConfig(tmp_path, tag="b"), [FakeShard(0, 0, 2)], FakeRunner, "fake")
    with pytest.raises(trajectory.CollectionError, match="holds shard"):  # same stem, other counts
        produce(FakeConfig(tmp_path), [FakeShard(0, 0, 3)], FakeRunner, "fake")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_an_output_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "file").write_text("mine")
    with pytest.raises(ValueError, match="a file, not a folder"):
        produce(FakeConfig(tmp_path / "file"), [FakeShard(0, 0, 1)], FakeRunner, "fake")
    assert (tmp_path / "file").read_text() == "mine"

"""Offline scoring post-processes each detector's per-frame scores as the online monitor does."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

import aed_models.data
from aed_eval.scoring import EpisodeScorer, LoadedDetector
from tests.models.test_detectors import make_batch, tiny


class NoReader:
    def read(self, ref):
        return ref

    def close(self) -> None:
        pass


def test_episode_scorer_takes_the_running_max_of_detectors_without_memory(monkeypatch):
    batch, _ = make_batch(seed=3)
    rollout = {k: v[2:3] for k, v in batch["rollouts"].items()}  # one rollout of 8 frames
    monkeypatch.setattr(aed_models.data, "pad_sequences", lambda seqs: rollout)
    detectors = [
        LoadedDetector(name, tiny(name).eval(), Path(name)) for name in ("svdd_ed", "lstm_ed")
    ]
    demos = type("Demos", (dict,), {"camera": "front"})({0: batch["demos"]})
    scorer = EpisodeScorer(detectors, policy=None, demos=demos)
    scorer.reader.close()
    scorer.reader = NoReader()
    scores = scorer.score(SimpleNamespace(env_index=0, path=Path("shard.h5"), traj="traj_0"))
    per_frame = {d.name: d.model.score(rollout, batch["demos"])[0] for d in detectors}
    assert not torch.equal(per_frame["svdd_ed"], torch.cummax(per_frame["svdd_ed"], 0).values)
    np.testing.assert_allclose(
        scores["svdd_ed"], torch.cummax(per_frame["svdd_ed"], 0).values.double().numpy()
    )
    np.testing.assert_allclose(scores["lstm_ed"], per_frame["lstm_ed"].double().numpy())


def test_demonstrations_mix_optimal_and_suboptimal_ones_or_say_what_is_missing(monkeypatch):
    from aed_eval import scoring
    from aed_tasks.trajectory import EpisodeRef

    def demo(env: int, seed: int, suboptimal: bool) -> EpisodeRef:
        return EpisodeRef(
            Path("x.h5"),
            f"traj_{seed}",
            "demo",
            "PressButton",
            "novel",
            env,
            9,
            seed,
            True,
            suboptimal=suboptimal,
        )

    refs = [demo(0, s, s >= 3) for s in range(6)]
    collection = type("C", (), {"episodes": lambda self: refs})()
    monkeypatch.setattr(scoring.trajectory, "scan_collection", lambda root: collection)
    optimal = scoring.Demonstrations(Path("novel"), "novel", 3)
    assert [r.seed for r in optimal.refs[0]] == [0, 1, 2]
    mixed = scoring.Demonstrations(Path("novel"), "novel", 3, num_suboptimal=2)
    assert [(r.seed, r.suboptimal) for r in mixed.refs[0]] == [(0, False), (3, True), (4, True)]
    refs += [demo(1, s, False) for s in range(3)]  # environment 1 has no sub-optimal one
    assert scoring.Demonstrations(Path("novel"), "novel", 3).envs() == [0, 1]
    with pytest.raises(ValueError, match=r"environments \[1\].*1 optimal and 2 sub-optimal"):
        scoring.Demonstrations(Path("novel"), "novel", 3, num_suboptimal=2)
    with pytest.raises(ValueError, match="num_suboptimal=4"):
        scoring.Demonstrations(Path("novel"), "novel", 3, num_suboptimal=4)

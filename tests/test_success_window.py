"""The success window: a rollout-level AUROC over each pair's frames up to the success, beside
the whole rollouts' (does a success's behaviour after it decide the ranking?)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from aed_eval import metrics
from aed_eval.results import stale_markdown, write_result
from aed_eval.results import success_window as window


def test_pairs_compare_each_failure_over_the_frames_up_to_the_success():
    success = np.array([0.1, 0.2, 0.9])  # succeeds at step 1, then its score jumps
    failures = [np.array([0.1, 0.3, 0.3]), np.array([0.2, 0.2, 0.2]), np.array([0.0, 0.1])]
    whole = metrics.success_window_pairs([success], [2], failures)
    assert whole.tolist() == [[0.0, 0.0, 0.0]]  # 0.9 above every failure
    pairs = metrics.success_window_pairs([success], [1], failures)
    assert pairs.tolist() == [[1.0, 0.5, 0.0]]  # above, tied, below the success's 0.2
    low, high = metrics.pairs_interval(np.array([[1.0, 0.5, 0.0], [1.0, 1.0, 0.0]]), 200)
    assert 0.0 <= low <= 7 / 12 <= high <= 1.0
    with pytest.raises(ValueError, match="success 0: success step 3 outside its 3 frames"):
        metrics.success_window_pairs([success], [3], failures)
    with pytest.raises(ValueError, match="need successful and failed rollouts"):
        metrics.success_window_pairs([], [], failures)


def write_scores(folder: Path) -> Path:
    """An evaluation folder: two successes (env 0 and 1) and two failures of one detector."""
    folder.mkdir(parents=True)
    episodes = [
        {"env_index": 0, "seed": 1, "success": True},
        {"env_index": 1, "seed": 2, "success": True},
        {"env_index": 0, "seed": 3, "success": False},
        {"env_index": 1, "seed": 4, "success": False},
    ]
    curves = [
        [0.1, 0.1, 0.9, 0.9],
        [0.2, 0.2, 0.2, 0.2],
        [0.3, 0.3, 0.3, 0.3],
        [0.0, 0.5, 0.5, 0.5],
    ]
    results = {"task": "PressButton", "policy": "dct", "policy_sha256": "ab" * 32}
    (folder / "results.json").write_text(json.dumps({**results, "ending": "horizon"}))
    scores = {"rollouts": {"episodes": episodes, "scores": {"probe": curves}}}
    (folder / "scores.json").write_text(json.dumps(scores))
    return folder


def test_the_record_sets_the_window_beside_the_whole_rollouts(tmp_path, monkeypatch):
    monkeypatch.setattr(window, "too_small", lambda outcomes: False)  # two of each suffice here
    monkeypatch.setattr(window, "success_steps", lambda *_: {(0, 1): 1, (1, 2): 2})
    record = window.success_window_record(write_scores(tmp_path / "eval"), tmp_path, 200)
    probe = record["detectors"]["probe"]
    # whole: the first success's 0.9 tops both failures, the second's 0.2 neither
    assert probe["whole_auroc"] == pytest.approx(0.5)
    # up to step 1 the first success has 0.1: both failures (0.3, 0.5) above it
    assert probe["window_auroc"] == pytest.approx(1.0)
    assert probe["max_after_success"] == pytest.approx(0.5)
    assert record["success_steps"] == [1, 2] and record["successes"] == 2
    written = write_result(tmp_path / "out" / "PressButton_dct.json", record)
    assert "| probe | 0.500 [" in written[1].read_text()
    assert stale_markdown(tmp_path / "out") == []


def test_a_success_without_its_step_or_another_ending_is_named(tmp_path, monkeypatch):
    folder = write_scores(tmp_path / "eval")
    monkeypatch.setattr(window, "too_small", lambda outcomes: False)
    monkeypatch.setattr(window, "success_steps", lambda *_: {(0, 1): 1})
    with pytest.raises(ValueError, match="no success step for 1 scored successes"):
        window.success_window_record(folder, tmp_path / "rollouts")
    results = json.loads((folder / "results.json").read_text())
    (folder / "results.json").write_text(json.dumps({**results, "ending": "success"}))
    with pytest.raises(ValueError, match="rollouts end at success, not the horizon"):
        window.success_window_record(folder, tmp_path / "rollouts")


def test_a_case_with_too_few_of_an_outcome_is_recorded_as_such(tmp_path, monkeypatch):
    """Fewer than 5 successes or failures: no AUROC, and the table says why (the main
    report's rule); the rollouts are not read."""
    monkeypatch.setattr(window, "success_steps", lambda *_: pytest.fail("rollouts read"))
    record = window.success_window_record(write_scores(tmp_path / "eval"), tmp_path)
    assert record["detectors"] == {} and (record["successes"], record["failures"]) == (2, 2)
    md = write_result(tmp_path / "out" / "PressButton_dct.json", record)[1].read_text()
    assert "2 successes against 2 failures, fewer than 5 of an outcome: too few to rank" in md

"""The embedding figure's numbers and rendering (`aed_eval.embeddings`), on made-up points."""

from __future__ import annotations

import numpy as np
import pytest

from aed_eval.embeddings import neighbourhood, tsne
from aed_eval.results import load_record, write_result


def two_kinds(separated: bool, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Six episodes of 20 frames; the last three turn erroneous at frame 10. Separated: error
    frames lie far from normal ones and every frame's place follows its progress."""
    rng = np.random.default_rng(seed)
    episode = np.repeat(np.arange(6), 20)
    progress = np.tile(np.linspace(0, 1, 20), 6)
    labels = (episode >= 3) & (np.tile(np.arange(20), 6) >= 10)
    if separated:
        x = np.stack([progress, 10.0 * labels], 1) + 0.01 * rng.normal(size=(120, 2))
    else:
        x = rng.normal(size=(120, 8))
    return x, episode, labels, progress


def test_neighbourhood_tells_clustered_embeddings_from_noise():
    clustered = neighbourhood(*two_kinds(True), k=5)
    noise = neighbourhood(*two_kinds(False), k=5)
    assert clustered["label_agreement"] == 1.0 and clustered["progress_gap"] < 0.1
    assert abs(noise["label_agreement"] - noise["chance"]) < 0.1
    assert noise["progress_gap"] > 0.25
    assert clustered["chance"] == pytest.approx(0.25**2 + 0.75**2)


def test_neighbours_of_the_frames_own_episode_are_left_out():
    x, episode, labels, progress = two_kinds(True)
    x = x + 100.0 * episode[:, None]  # every episode far from the others
    same_episode_only = neighbourhood(x, episode, labels, progress, k=3)
    assert same_episode_only["progress_gap"] > 0.1  # consecutive frames did not count


def test_the_record_renders_a_panel_per_detector(tmp_path):
    x, episode, labels, progress = two_kinds(True)
    episodes = [
        {"env_index": i, "seed": i, "frames": 20, "onset_frame": 10 if i >= 3 else None}
        for i in range(6)
    ]
    record = {
        "kind": "embeddings",
        "task": "PressButton",
        "policy": "scan",
        "neighbours": 5,
        "perplexity": 5.0,
        "seed": 0,
        "episodes": episodes,
        "detectors": {
            name: {
                "dim": 2,
                **neighbourhood(x, episode, labels, progress, 5),
                "points": np.round(tsne(x, 5.0, 0), 2).tolist(),
            }
            for name in ("lstm_ed", "probe")
        },
    }
    written = write_result(tmp_path / "PressButton_scan.json", record)
    assert [p.suffix for p in written] == [".json", ".md", ".png"]
    table = written[1].read_text()
    assert "| probe | 2 | 1.000 | 0.625 |" in table and "3 successes, 3 failures" in table
    assert len(load_record(written[0])["detectors"]["probe"]["points"]) == 120

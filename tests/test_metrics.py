"""Rollout-level AUROC / AUPRC, the conformal threshold, alarm rates and detection delays."""

from __future__ import annotations

import numpy as np
import pytest

from aed_eval import metrics


def curves(maxima, failed, kind="probability"):
    maxima = np.asarray(maxima, dtype=float)
    return metrics.rollout_curves(
        maxima, np.asarray(failed, dtype=bool), metrics.thresholds(kind, maxima)
    )


FAILED = np.array([True] * 6 + [False] * 14)  # prevalence 0.3


def test_perfect_scores():
    c = curves(np.where(FAILED, 0.9, 0.1), FAILED)
    assert c.auroc == pytest.approx(1.0) and c.auprc == pytest.approx(1.0)


def test_inverted_scores():
    c = curves(np.where(FAILED, 0.1, 0.9), FAILED)
    assert c.auroc == pytest.approx(0.0, abs=1e-12)
    assert c.auprc == pytest.approx(FAILED.mean())  # recall arrives only with every false alarm


def test_constant_scores():
    c = curves(np.full(len(FAILED), 0.4), FAILED)
    assert c.auroc == pytest.approx(0.5) and c.auprc == pytest.approx(FAILED.mean())


def test_random_scores_are_chance():
    rng = np.random.default_rng(0)
    failed = rng.uniform(size=4000) < 0.25
    c = curves(rng.uniform(size=4000), failed)
    assert c.auroc == pytest.approx(0.5, abs=0.03) and c.auprc == pytest.approx(
        failed.mean(), abs=0.03
    )


@pytest.mark.parametrize("seed", range(5))
def test_threshold_sweep_agrees_with_the_exact_auroc(seed):
    """Scores on a 1/1000 grid: every pair of distinct values has a threshold between them."""
    rng = np.random.default_rng(seed)
    failed = rng.uniform(size=300) < 0.4
    maxima = np.round(np.clip(rng.normal(0.5 + 0.15 * failed, 0.2), 0, 1), 3)
    c = curves(maxima, failed)
    assert c.auroc == pytest.approx(metrics.exact_auroc(maxima[failed], maxima[~failed]), abs=1e-9)
    # average precision, computed directly over the distinct maxima
    ap, previous_recall = 0.0, 0.0
    for t in np.unique(maxima)[::-1]:
        alarmed = maxima >= t
        recall = (alarmed & failed).sum() / failed.sum()
        ap += (recall - previous_recall) * (alarmed & failed).sum() / alarmed.sum()
        previous_recall = recall
    assert c.auprc == pytest.approx(ap, abs=1e-9)


def test_any_frame_rule_uses_the_maximum_and_distances_their_range():
    scores = [np.array([0.1, 0.8, 0.2]), np.array([0.3, 0.3]), np.array([12.0, 40.0])]
    np.testing.assert_allclose(metrics.rollout_maxima(scores), [0.8, 0.3, 40.0])
    grid = metrics.thresholds("distance", np.array([3.0, 50.0]))
    assert len(grid) == metrics.NUM_THRESHOLDS and grid[0] == 3.0 and grid[-1] == 50.0
    c = curves([3.0, 10.0, 20.0, 50.0], [False, False, True, True], kind="distance")
    assert c.auroc == pytest.approx(1.0)
    with pytest.raises(ValueError, match="rollout 1 has no scores"):
        metrics.rollout_maxima([np.ones(2), np.ones(0)])


@pytest.mark.parametrize(("n", "alpha"), [(20, 0.1), (100, 0.05), (50, 0.2)])
def test_conformal_threshold_holds_its_false_alarm_rate(n, alpha):
    """Over many calibration draws the false-alarm rate on new successes lies in the conformal
    band [alpha - 1/(n+1), alpha]; 4000 draws put the mean within 0.006 of it by chance at most
    once in a million, so a wrong rule (say the alpha-quantile itself) cannot pass."""
    rng = np.random.default_rng(n)
    rates = []
    for _ in range(4000):
        calibration = rng.gamma(2.0, size=n)
        threshold = metrics.conformal_threshold(calibration, alpha)
        rates.append(np.mean(rng.gamma(2.0, size=200) >= threshold))
    mean = float(np.mean(rates))
    assert alpha - 1 / (n + 1) - 0.006 <= mean <= alpha + 0.006, mean


def test_conformal_threshold_edge_cases():
    assert metrics.conformal_threshold(np.array([0.2, 0.4]), 0.1) == float(
        "inf"
    )  # too few to promise 10%
    assert metrics.conformal_threshold(np.arange(19.0), 0.1) > 17.0
    with pytest.raises(ValueError, match="alpha=1.5"):
        metrics.conformal_threshold(np.ones(5), 1.5)


def test_alarm_rates_and_detection_delays():
    scores = [
        np.array([0.0, 0.2, 0.9, 0.9]),
        np.array([0.1, 0.1, 0.1]),
        np.array([0.0, 0.95]),
        np.array([0.3]),
    ]
    failed = np.array([True, True, False, False])
    rates = metrics.alarm_rates(scores, failed, 0.5)
    assert (rates.tpr, rates.tnr, rates.balanced_accuracy) == (0.5, 0.5, 0.5)
    assert rates.detection_step_mean == 2.0 and rates.detection_fraction_mean == pytest.approx(
        2 / 3
    )
    delays = metrics.detection_delays(
        scores[:2] + [np.array([0.9, 0.0, 0.0, 0.0])], [1, 1, 2], 0.5, window=1
    )
    assert delays["counts"] == {"early": 1, "on_time": 1, "late": 0, "missed": 1} and delays[
        "delays"
    ] == [1, -2]


def test_frame_auroc_and_reference_scores():
    assert (
        metrics.frame_auroc(
            [np.array([0.1, 0.9]), np.array([0.2, 0.3])], [np.array([0, 1]), np.array([0, 0])]
        )
        == 1.0
    )
    lengths = [3, 5]
    time_only = metrics.time_only_scores(lengths, horizon=4)
    np.testing.assert_allclose(time_only[1], [0, 0.25, 0.5, 0.75, 1.0])
    assert [len(s) for s in metrics.random_scores(lengths)] == lengths


def test_time_matched_auroc_compares_frames_of_the_same_bin_only():
    labels = [np.array([0, 0, 1, 1]), np.array([0, 0, 0, 0])]
    scores = [np.array([0.0, 0.0, 0.5, 0.5]), np.array([0.0, 0.0, 0.6, 0.4])]
    # bins of 2: bin 0 has no error frame; bin 1 pairs (0.5, 0.5) x (0.6, 0.4): 2 wins of 4
    assert metrics.time_matched_auroc(scores, labels, bin_width=2) == pytest.approx(0.5)
    assert metrics.frame_auroc(scores, labels) == pytest.approx(
        (4 * 2 + 2) / 12
    )  # every pair counts
    time_only = [np.arange(4.0), np.arange(4.0)]
    assert metrics.time_matched_auroc(time_only, labels, bin_width=1) == pytest.approx(0.5)
    assert np.isnan(metrics.time_matched_auroc([np.zeros(2)], [np.array([0, 0])]))
    with pytest.raises(ValueError, match="bin_width"):
        metrics.time_matched_auroc(scores, labels, bin_width=0)


def test_single_class_gives_undefined_areas():
    for failed in (np.ones(6, dtype=bool), np.zeros(6, dtype=bool)):
        c = metrics.rollout_curves(
            np.linspace(0, 1, 6), failed, metrics.thresholds("probability", None)
        )
        assert np.isnan(c.auroc) and np.isnan(c.auprc)

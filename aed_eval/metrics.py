"""Metrics of the AED protocol: rollout-level AUROC / AUPRC, calibrated thresholds, delays.

Rollout-level accuracy (the paper's appendix, after MoMaRT): a rollout raises an alarm at a
threshold when its maximum score reaches it (failed + alarm = TP, succeeded + alarm = FP), so
every count depends on each rollout's maximum alone. Curves sweep 5000 thresholds over [0, 1]
(probabilities) or over the observed range (unbounded scores); AUPRC is the average precision.
Beyond the paper: split-conformal thresholds (`conformal_threshold`), rates at one threshold
(`alarm_rates`), frame-level AUROC and detection delays on labelled episodes, and 95%
intervals (`stratified_bootstrap`, `proportion_interval`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

NUM_THRESHOLDS = 5000
NUM_BOOTSTRAP = 1000
LEVEL = 0.95


def rollout_maxima(scores: Sequence[np.ndarray]) -> np.ndarray:
    """The maximum score of each rollout (what the any-frame alarm rule compares)."""
    if not len(scores):
        raise ValueError("no rollouts to score")
    for i, s in enumerate(scores):
        if len(s) == 0:
            raise ValueError(f"rollout {i} has no scores")
        if not np.all(np.isfinite(s)):
            raise ValueError(f"rollout {i} has non-finite scores")
    return np.asarray([float(np.max(s)) for s in scores])


def thresholds(
    kind: str, maxima: np.ndarray | None = None, num: int = NUM_THRESHOLDS
) -> np.ndarray:
    """`num` thresholds spread evenly over [0, 1] (`probability`) or the observed range
    (`distance`)."""
    if kind == "probability":
        return np.linspace(0.0, 1.0, num)
    if kind == "distance":
        if maxima is None or not len(maxima):
            raise ValueError("distance thresholds need the observed scores")
        return np.linspace(float(np.min(maxima)), float(np.max(maxima)), num)
    raise ValueError(f"kind={kind!r}: probability or distance")


@dataclass
class Curves:
    """Confusion counts at every threshold (ascending) and the areas under the curves."""

    thresholds: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    positives: int  # failed rollouts
    negatives: int  # successful rollouts

    @property
    def tpr(self) -> np.ndarray:
        return self.tp / max(self.positives, 1)

    @property
    def fpr(self) -> np.ndarray:
        return self.fp / max(self.negatives, 1)

    @property
    def precision(self) -> np.ndarray:
        alarms = self.tp + self.fp
        return np.divide(self.tp, alarms, out=np.ones_like(self.tp, dtype=float), where=alarms > 0)

    @property
    def auroc(self) -> float:
        if not self.positives or not self.negatives:
            return float("nan")
        fpr = np.concatenate([[1.0], self.fpr, [0.0]])  # thresholds ascending: rates fall
        tpr = np.concatenate([[1.0], self.tpr, [0.0]])
        return float(np.sum((fpr[:-1] - fpr[1:]) * (tpr[:-1] + tpr[1:]) / 2))  # trapezoids

    @property
    def auprc(self) -> float:
        """Average precision: sum over thresholds (descending) of recall gain x precision.

        Undefined (nan) with a single class, as AUROC: with no successful rollout every score,
        even a constant, would get 1.0, and a report ranking detectors on it would rank noise.
        """
        if not self.positives or not self.negatives:
            return float("nan")
        recall = self.tpr[::-1]
        precision = self.precision[::-1]
        gains = np.diff(np.concatenate([[0.0], recall]))
        return float(np.sum(gains * precision))


def rollout_curves(maxima: np.ndarray, failed: np.ndarray, grid: np.ndarray) -> Curves:
    """Counts of the paper's accuracy function at every threshold of `grid`."""
    maxima, failed = np.asarray(maxima, dtype=float), np.asarray(failed, dtype=bool)
    if maxima.shape != failed.shape:
        raise ValueError(f"{maxima.shape[0]} scores but {failed.shape[0]} outcomes")
    order = np.sort(maxima[failed]), np.sort(maxima[~failed])
    # alarms at threshold t: rollouts whose maximum >= t
    tp = len(order[0]) - np.searchsorted(order[0], grid, side="left")
    fp = len(order[1]) - np.searchsorted(order[1], grid, side="left")
    return Curves(
        np.asarray(grid, dtype=float),
        tp.astype(float),
        fp.astype(float),
        int(failed.sum()),
        int((~failed).sum()),
    )


def exact_auroc(positive: np.ndarray, negative: np.ndarray) -> float:
    """P(a positive scores above a negative), ties counted half (Mann-Whitney U / (P N))."""
    positive, negative = np.asarray(positive, dtype=float), np.asarray(negative, dtype=float)
    if not len(positive) or not len(negative):
        return float("nan")
    negative = np.sort(negative)
    below = np.searchsorted(negative, positive, side="left")
    ties = np.searchsorted(negative, positive, side="right") - below
    return float((below + 0.5 * ties).sum() / (len(positive) * len(negative)))


def frame_auroc(scores: Sequence[np.ndarray], labels: Sequence[np.ndarray]) -> float:
    """Frame-level AUROC over episodes with true labels (1 = error frame)."""
    s = np.concatenate([np.asarray(x, dtype=float) for x in scores])
    y = np.concatenate([np.asarray(x, dtype=bool) for x in labels])
    if s.shape != y.shape:
        raise ValueError(f"{s.shape[0]} frame scores but {y.shape[0]} frame labels")
    return exact_auroc(s[y], s[~y])


def time_matched_auroc(
    scores: Sequence[np.ndarray], labels: Sequence[np.ndarray], bin_width: int = 5
) -> float:
    """Frame-level AUROC counting only (error, normal) pairs from the same time bin.

    Error frames come after an onset, so they are late in an episode: a score that only grows
    with time already ranks them high (`time_only`). Comparing only frames of the same bin of
    `bin_width` steps removes that: the frame index alone scores about 0.5 here. Bins without
    both kinds of frame do not count; nan when no bin has both.
    """
    if bin_width < 1:
        raise ValueError(f"bin_width={bin_width}: must be >= 1")
    s = np.concatenate([np.asarray(x, dtype=float) for x in scores])
    y = np.concatenate([np.asarray(x, dtype=bool) for x in labels])
    if s.shape != y.shape:
        raise ValueError(f"{s.shape[0]} frame scores but {y.shape[0]} frame labels")
    bins = np.concatenate([np.arange(len(x)) // bin_width for x in labels])
    weighted, pairs = 0.0, 0
    for b in np.unique(bins):
        pos, neg = s[(bins == b) & y], s[(bins == b) & ~y]
        if len(pos) and len(neg):
            weighted += exact_auroc(pos, neg) * len(pos) * len(neg)
            pairs += len(pos) * len(neg)
    return weighted / pairs if pairs else float("nan")


def success_window_pairs(
    successes: Sequence[np.ndarray], success_steps: Sequence[int], failures: Sequence[np.ndarray]
) -> np.ndarray:
    """W[i, j]: 1 when failed rollout j's maximum over frames 0..k_i is above successful
    rollout i's (k_i: its first success step), 0.5 on a tie, else 0; its mean is an AUROC.

    Every rollout runs the horizon, but the detectors trained on episodes that end at success;
    comparing each pair over the frames up to the success leaves out what a success does after
    it (the paper's ending instead also cuts the failures short, which credits length).
    """
    if not len(successes) or not len(failures):
        raise ValueError("success-window pairs need successful and failed rollouts")
    if len(success_steps) != len(successes):
        raise ValueError(f"{len(success_steps)} success steps for {len(successes)} successes")
    prefix_max = [np.maximum.accumulate(np.asarray(f, dtype=float)) for f in failures]
    pairs = np.empty((len(successes), len(failures)))
    for i, (s, k) in enumerate(zip(successes, success_steps, strict=True)):
        if not 0 <= k < len(s):
            raise ValueError(f"success {i}: success step {k} outside its {len(s)} frames")
        own = float(np.max(s[: k + 1]))
        theirs = np.asarray([m[min(k, len(m) - 1)] for m in prefix_max])
        pairs[i] = (theirs > own) + 0.5 * (theirs == own)
    return pairs


def pairs_interval(
    pairs: np.ndarray, num: int = NUM_BOOTSTRAP, seed: int = 0
) -> tuple[float, float]:
    """95% interval of a pairwise AUROC (the mean of `pairs`, successes x failures), the
    successes and the failures resampled each within their own."""
    rows, cols = pairs.shape
    return stratified_bootstrap(
        lambda idx: float(pairs[np.ix_(idx[:rows], idx[rows:] - rows)].mean()),
        [np.arange(rows), rows + np.arange(cols)],
        num,
        seed=seed,
    )


# --- calibrated threshold ------------------------------------------------------------------------
def conformal_threshold(success_maxima: np.ndarray, alpha: float) -> float:
    """Split-conformal alarm threshold from held-out successful rollouts' maximum scores.

    With the calibration maxima and a new successful rollout's maximum exchangeable, the
    ceil((n + 1)(1 - alpha))-th smallest calibration maximum m_(k) satisfies
    P(new maximum > m_(k)) <= alpha. Alarms fire at score >= threshold, so the threshold is
    the next float above m_(k). When n is too small for alpha (k > n) no finite threshold
    guarantees it: +inf (never alarm) is returned.
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha={alpha}: must lie in (0, 1)")
    m = np.sort(np.asarray(success_maxima, dtype=float))
    if not len(m):
        raise ValueError("no successful rollouts to calibrate on")
    k = math.ceil((len(m) + 1) * (1.0 - alpha))
    if k > len(m):
        return float("inf")
    return float(np.nextafter(m[k - 1], np.inf))


@dataclass
class AlarmRates:
    threshold: float
    tpr: float  # failed rollouts alarmed
    tnr: float  # successful rollouts not alarmed
    balanced_accuracy: float
    false_alarms: int  # successful rollouts alarmed
    successes: int
    false_alarm_rate: float  # 1 - TNR, the rate a calibration promises to bound
    false_alarm_interval: tuple[float, float]  # Wilson 95%
    detection_step_mean: float  # first alarm step of alarmed failed rollouts (nan if none)
    detection_fraction_mean: float  # the same as a fraction of the rollout's length

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def first_alarm(scores: np.ndarray, threshold: float) -> int | None:
    """Index of the first frame whose score reaches the threshold (None: no alarm)."""
    hits = np.flatnonzero(np.asarray(scores) >= threshold)
    return int(hits[0]) if len(hits) else None


def alarm_rates(scores: Sequence[np.ndarray], failed: np.ndarray, threshold: float) -> AlarmRates:
    """TPR / TNR / balanced accuracy, the realised false-alarm rate and detection time of the
    any-frame rule at one threshold."""
    failed = np.asarray(failed, dtype=bool)
    alarms = [first_alarm(s, threshold) for s in scores]
    alarmed = np.asarray([a is not None for a in alarms])
    tpr = float(alarmed[failed].mean()) if failed.any() else float("nan")
    tnr = float((~alarmed[~failed]).mean()) if (~failed).any() else float("nan")
    false_alarms, successes = int(alarmed[~failed].sum()), int((~failed).sum())
    steps = [a for a, f in zip(alarms, failed, strict=True) if f and a is not None]
    fractions = [
        a / max(len(s) - 1, 1)
        for a, s, f in zip(alarms, scores, failed, strict=True)
        if f and a is not None
    ]
    return AlarmRates(
        threshold=threshold,
        tpr=tpr,
        tnr=tnr,
        balanced_accuracy=(tpr + tnr) / 2,  # nan without both outcomes
        false_alarms=false_alarms,
        successes=successes,
        false_alarm_rate=false_alarms / successes if successes else float("nan"),
        false_alarm_interval=proportion_interval(false_alarms, successes),
        detection_step_mean=float(np.mean(steps)) if steps else float("nan"),
        detection_fraction_mean=float(np.mean(fractions)) if fractions else float("nan"),
    )


DELAY_CLASSES = ("early", "on_time", "late", "missed")


def detection_delays(
    scores: Sequence[np.ndarray], onsets: Sequence[int], threshold: float, window: int = 10
) -> dict[str, object]:
    """First alarm minus labelled onset (frames) on failures with true onsets.

    early: before the onset; on_time: within `window` frames after it; late: later; missed:
    no alarm at all. `onsets` index frames (frame t + 1 follows action t: a label onset at
    action k is frame k + 1).
    """
    delays, counts = [], dict.fromkeys(DELAY_CLASSES, 0)
    for s, onset in zip(scores, onsets, strict=True):
        alarm = first_alarm(s, threshold)
        if alarm is None:
            counts["missed"] += 1
            continue
        delay = alarm - int(onset)
        delays.append(delay)
        counts["early" if delay < 0 else "on_time" if delay <= window else "late"] += 1
    return {
        "counts": counts,
        "delays": delays,
        "median_delay": float(np.median(delays)) if delays else float("nan"),
        "window": window,
    }


# --- reference scores ----------------------------------------------------------------------------
def time_only_scores(lengths: Sequence[int], horizon: int) -> list[np.ndarray]:
    """Score = step / horizon: no input at all. Shows how much of a number is rollout length."""
    return [np.arange(n, dtype=float) / max(horizon, 1) for n in lengths]


def random_scores(lengths: Sequence[int], seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(0.0, 1.0, n) for n in lengths]


# --- intervals -----------------------------------------------------------------------------------
def stratified_bootstrap(
    statistic: Callable[[np.ndarray], float],
    groups: Sequence[np.ndarray],
    num: int = NUM_BOOTSTRAP,
    level: float = LEVEL,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile interval of `statistic(indices)` over resamples drawn within each group.

    Each replicate resamples every group (e.g. the failed and the successful rollouts' indices)
    with replacement to its own size, so that the class balance stays the observed one.
    Replicates where the statistic is undefined (nan) are dropped; (nan, nan) when all are.
    """
    groups = [np.asarray(g, dtype=int) for g in groups if len(g)]
    if not groups:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    values = np.asarray(
        [
            statistic(np.concatenate([rng.choice(g, size=len(g), replace=True) for g in groups]))
            for _ in range(num)
        ],
        dtype=float,
    )
    values = values[np.isfinite(values)]
    if not len(values):
        return float("nan"), float("nan")
    tail = 100 * (1 - level) / 2
    return float(np.percentile(values, tail)), float(np.percentile(values, 100 - tail))


def curve_intervals(
    maxima: np.ndarray,
    failed: np.ndarray,
    grid: np.ndarray,
    num: int = NUM_BOOTSTRAP,
    seed: int = 0,
) -> dict[str, tuple[float, float]]:
    """95% intervals of AUROC and AUPRC, rollouts resampled within each outcome class.

    The threshold grid stays the one of the observed rollouts (the sweep being measured).
    """
    maxima, failed = np.asarray(maxima, dtype=float), np.asarray(failed, dtype=bool)
    groups = [np.flatnonzero(failed), np.flatnonzero(~failed)]
    intervals = {}
    for name in ("auroc", "auprc"):
        intervals[name] = stratified_bootstrap(
            lambda idx, name=name: getattr(rollout_curves(maxima[idx], failed[idx], grid), name),
            groups,
            num,
            seed=seed,
        )
    return intervals


def rate_interval(
    outcomes: np.ndarray, num: int = NUM_BOOTSTRAP, seed: int = 0
) -> tuple[float, float]:
    """95% bootstrap interval of a rate (e.g. the policy's success rate) over its trials."""
    outcomes = np.asarray(outcomes, dtype=float)
    return stratified_bootstrap(
        lambda idx: float(outcomes[idx].mean()), [np.arange(len(outcomes))], num, seed=seed
    )


def proportion_interval(hits: int, trials: int, level: float = LEVEL) -> tuple[float, float]:
    """Wilson score interval of a proportion (a realised false-alarm rate).

    Unlike a bootstrap, it is not degenerate at 0 or n hits: 0 false alarms in 6 successes
    still allows a rate up to 0.39.
    """
    if trials <= 0:
        return float("nan"), float("nan")
    from statistics import NormalDist

    z = NormalDist().inv_cdf(0.5 + level / 2)
    p = hits / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = (
        z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    )
    return max(0.0, centre - half), min(1.0, centre + half)


def intervals_overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two (low, high) intervals share a point (unknown ones count as overlapping)."""
    if not all(np.isfinite(x) for x in (*a, *b)):
        return True
    return a[0] <= b[1] and b[0] <= a[1]

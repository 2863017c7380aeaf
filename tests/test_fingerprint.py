"""The code still resolves the same recipes, trains the same weights and records the same
episodes as when `tests/fixtures/fingerprint.json` was written (before the presets redesign)."""

from __future__ import annotations

import json
import math
import re
from typing import Any

import pytest

from tests import fingerprint

EXACT = ("recipes", "protocol", "demo")
GONE = object()  # "value now" of a field removed on purpose
ABSENT = object()  # "value then" of a field added on purpose
FROZEN = (
    "the mini policies' visual head is the task's scene encoder, frozen (aed train-encoder); "
    "they train on its cached features, which are not shifted (the encoder was)"
)
LOCALIZER = (
    "the mini policies read where the demonstrations' stage targets are in the rollout's first "
    "frame (the task's target localizer, aed train-localizer), matched on 4-pixel cells at the "
    "nearest surface's depth within 4 pixels, or at the demonstrations' height of the stage "
    "where that depth is more than 3 cm from it"
)
CHUNK = (
    "the mini DCT and SCAN predict the next 10 actions at every step and act on their temporal "
    "ensemble (ACT's action chunking); NaiveDC and the paper's policies predict one"
)
POINTER = (
    "the mini policies' stage-target head chooses among the offsets to the located targets "
    "(plus a linear residual), and its prediction reaches the position action through a learned "
    "per-axis gain: the linear head's actor ignored the located x"
)
MINI_ENVS = (
    "the mini protocol is #20's recipe: up to 23 training + 4 calibration base environments and "
    "up to 18 novel ones, a smaller catalogue giving all it has"
)
# Environments of the mini protocol by task (None: the whole catalogue): base collection, novel
# collection, base rollouts, novel rollouts.
MINI_ENV_COUNTS = {
    "CloseDrawer": (None, None, None, None),
    "PressButton": (None, None, 18, None),
    "PickPlace": (27, 18, 18, 18),
    "MoveGlassCup": (27, 18, 18, 18),
    "OrganizeTable": (27, 18, 18, 18),
    "BackToBox": (27, None, 18, None),
    "FactoryPacking": (27, None, 18, None),
}
# Changes made on purpose since the fingerprint was stored: (path, value then, value now, why).
INTENDED = [
    *(
        (
            ("recipes", f"model/{name}/{profile}", "action_chunk"),
            ABSENT,
            10 if profile == "mini" and name != "naive_dc" else 1,
            CHUNK,
        )
        for name in ("naive_dc", "dct", "scan")
        for profile in fingerprint.PROFILES
    ),
    *(
        (("protocol", f"{stage}/mini/{task}/{split}", "num_envs"), 4, now, MINI_ENVS)
        for task, row in MINI_ENV_COUNTS.items()
        for (stage, split), now in zip(
            (("collect", "base"), ("collect", "novel"), ("rollout", "base"), ("rollout", "novel")),
            row,
            strict=True,
        )
    ),
    *(
        (
            ("recipes", f"model/{name}/{profile}", "running_max"),
            True,
            GONE,
            "the running maximum is one post-processing step of scoring and monitoring for the "
            "detectors without memory (aed_models.detectors.postprocess), no longer a field",
        )
        for name in ("svdd_ed", "taskemb_ed", "rnd_oe")
        for profile in fingerprint.PROFILES
    ),
    *(
        (
            ("recipes", f"model/{name}/{profile}", "frozen_encoder"),
            ABSENT,
            profile == "mini",
            FROZEN,
        )
        for name in ("naive_dc", "dct", "scan")
        for profile in fingerprint.PROFILES
    ),
    *(
        (("recipes", f"train/{name}/mini/{task}", "shift"), 4, 0, FROZEN)
        for name in ("naive_dc", "dct", "scan")
        for task in fingerprint.TASKS
    ),
    (("demo", "mini", "policy", 0, "shift"), 4, 0, FROZEN),
    *(
        (
            ("demo", "mini", "collect", 3, count),
            1,
            3,
            "the demo's policy rarely succeeds in 20 minutes of two cores: its minutes go to "
            "labelled novel episodes, whose table does not depend on the policy",
        )
        for count in ("num_successes", "num_failures")
    ),
    *(
        (
            ("recipes", f"model/{name}/{profile}", "localizer"),
            ABSENT,
            {
                "width": 32,
                "dim": 32,
                "num_targets": 1,
                "depth_window": 4,
                "stride": 4,
                "height_tolerance": 0.03,
            }
            if profile == "mini"
            else None,
            LOCALIZER,
        )
        for name in ("naive_dc", "dct", "scan")
        for profile in fingerprint.PROFILES
    ),
    *(
        (
            ("recipes", f"model/{name}/{profile}", "subgoal_head"),
            ABSENT,
            "pointer" if profile == "mini" else "linear",
            POINTER,
        )
        for name in ("naive_dc", "dct", "scan")
        for profile in fingerprint.PROFILES
    ),
]

# Weights whose keys were renamed on purpose, values unchanged: (part, model, why); the model's
# own rename of old checkpoints' keys maps the stored keys.
RENAMED = [
    ("detectors", "dct_ed", "DCTED on the shared attention blocks: q/k/v for query/key/value"),
]


def renamed_keys(part: str, model: str, weights: dict) -> dict:
    """`weights` (key -> summary) under the keys the model loads them as today."""
    from aed_models.detectors import make_detector

    assert part == "detectors", part
    now = make_detector(model).upgrade_state_dict(weights)
    assert len(now) == len(weights) and now != weights, f"{part}/{model}: nothing renamed"
    return now


def with_intended_changes(stored: dict) -> dict:
    """`stored` with each intended change applied, after checking it held the value of then."""
    for part, model, _why in RENAMED:
        stored[part][model] = renamed_keys(part, model, stored[part][model])
    for path, then, now, _why in INTENDED:
        *parents, leaf = path
        node = stored
        for key in parents:
            node = node[key]
        if then is ABSENT:
            assert leaf not in node, f"{path}: stored, the intended change says it was absent"
        else:
            assert node[leaf] == then, (
                f"{path}: stored {node[leaf]!r}, the intended change says {then!r}"
            )
        if now is GONE:
            del node[leaf]
        else:
            node[leaf] = now
    return stored


CLOSE = ("policies", "detectors", "episodes")  # floats: the same up to the CPU's summation order


def differences(expected: Any, actual: Any, path: str = "", rel: float = 0.0) -> list[str]:
    if isinstance(expected, dict) and isinstance(actual, dict):
        found = [f"{path}/{k}: missing" for k in sorted(set(expected) - set(actual))]
        found += [f"{path}/{k}: unexpected" for k in sorted(set(actual) - set(expected))]
        for k in sorted(set(expected) & set(actual)):
            found += differences(expected[k], actual[k], f"{path}/{k}", rel)
        return found
    if isinstance(expected, list) and isinstance(actual, list) and len(expected) == len(actual):
        return [
            d
            for i, (e, a) in enumerate(zip(expected, actual, strict=True))
            for d in differences(e, a, f"{path}[{i}]", rel)
        ]
    both_numbers = all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in (expected, actual)
    )
    if rel and both_numbers and isinstance(expected, float):
        return (
            []
            if math.isclose(expected, actual, rel_tol=rel, abs_tol=1e-4)
            else [f"{path}: {expected} != {actual}"]
        )
    return (
        []
        if expected == actual and type(expected) is type(actual)
        else [f"{path}: {expected!r} != {actual!r}"]
    )


@pytest.fixture(scope="module")
def stored_and_now():
    return with_intended_changes(
        json.loads(fingerprint.STORED.read_text())
    ), fingerprint.fingerprint()


# A conv's gradient sums over every pixel of the batch: the reductions whose order differs most
# between CPUs' kernels (AVX2, AVX-512, AMX), and the tiny trainings carry that to a few percent
# of a first conv's bias. The visual backbones' convs (sum, sum of |x|) are compared at this
# share of their sum of |x|; every other tensor at 1e-3.
CONV = re.compile(r"(^|\.)convs\.\d+\.(weight|bias)$")
CONV_REL = 0.1


def weight_differences(expected: dict, actual: dict, path: str) -> list[str]:
    """Trained weights (model -> tensor -> [sum, sum of |x|]): the same tensors, each at 1e-3,
    the backbones' convs at `CONV_REL` of their size."""
    found = differences(
        {m: dict.fromkeys(t) for m, t in expected.items()},
        {m: dict.fromkeys(t) for m, t in actual.items()},
        path,
    )
    for model, tensors in expected.items():
        for key, (total, size) in tensors.items():
            now = actual.get(model, {}).get(key)
            if now is None:
                continue
            if not CONV.search(key):
                found += differences([total, size], now, f"{path}/{model}/{key}", rel=1e-3)
            elif not (
                abs(now[0] - total) <= CONV_REL * size
                and math.isclose(now[1], size, rel_tol=CONV_REL)
            ):
                found.append(f"{path}/{model}/{key}: {[total, size]} != {now}")
    return found


@pytest.mark.parametrize("part", EXACT + CLOSE)
def test_matches_the_stored_fingerprint(stored_and_now, part):
    stored, now = stored_and_now
    if part in ("policies", "detectors"):
        found = weight_differences(stored[part], now[part], part)
    else:
        found = differences(stored[part], now[part], part, rel=1e-3 if part in CLOSE else 0.0)
    assert not found, "\n".join(found[:20])


def test_a_conv_is_compared_at_its_size_and_the_rest_at_1e_3():
    stored = {"m": {"convs.0.bias": [0.10, 1.0], "head.weight": [2.0, 4.0]}}
    assert (
        weight_differences(
            stored, {"m": {"convs.0.bias": [0.15, 1.02], "head.weight": [2.0, 4.0]}}, "w"
        )
        == []
    )
    assert weight_differences(
        stored, {"m": {"convs.0.bias": [0.3, 1.0], "head.weight": [2.0, 4.0]}}, "w"
    ) == ["w/m/convs.0.bias: [0.1, 1.0] != [0.3, 1.0]"]
    assert weight_differences(
        stored, {"m": {"convs.0.bias": [0.1, 1.0], "head.weight": [2.01, 4.0]}}, "w"
    ) == ["w/m/head.weight[0]: 2.0 != 2.01"]
    assert weight_differences(stored, {"m": {"head.weight": [2.0, 4.0]}}, "w") == [
        "w/m/convs.0.bias: missing"
    ]


def test_the_comparison_can_fail():
    assert differences({"a": [1.0, 2]}, {"a": [1.01, 2]}, rel=1e-3) == ["/a[0]: 1.0 != 1.01"]
    assert differences({"a": 1}, {"b": 1}) == ["/a: missing", "/b: unexpected"]
    assert differences({"x": (8)}, {"x": 8.0}) == ["/x: 8 != 8.0"]

"""The frozen policy's feature cache is keyed by everything its contents depend on (policy
checkpoint, seed, number of demonstrations) and has one writer at a time."""

from __future__ import annotations

import json
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from aed_models.checkpoint import file_sha256
from aed_models.data import load_episodes
from aed_models.train.feature_cache import FeatureCache, FeatureCacheError
from aed_tasks.locks import LOCK_NAME, folder_lock
from tests.helpers import write_synthetic_collection


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> Path:
    """Two environments; per env 4 demos, 2 successes, 1 failure (synthetic frames)."""
    counts = {"demo": 4, "agent_success": 2, "agent_failure": 1}
    return write_synthetic_collection(tmp_path_factory.mktemp("collection"), counts, steps=10)


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> tuple[object, str]:
    """A tiny untrained NaiveDC and its checkpoint's sha256."""
    from aed_models.nn import VisualHeadConfig
    from aed_models.policies import POLICIES, load_policy, make_policy, save_policy

    torch.manual_seed(0)
    config = POLICIES.preset(
        "naive_dc",
        "mini",
        visual=VisualHeadConfig(arch="small_cnn", out_dim=16, width=4),
        localizer=None,
        subgoal_head="linear",  # the pointer head needs a localizer
    )
    path = tmp_path_factory.mktemp("policy") / "policy.pt"
    save_policy(path, make_policy("naive_dc", config).eval())
    return load_policy(path), file_sha256(path)


def meta(cache: FeatureCache, shard: Path) -> dict:
    with np.load(cache.path_for(shard)) as data:
        return json.loads(str(data["meta"]))


def test_another_seed_or_number_of_demos_is_another_cache(collection, policy, tmp_path):
    model, sha = policy
    episodes = load_episodes(collection)
    ref = next(e for e in episodes if e.role == "agent_success")
    base = FeatureCache(tmp_path, sha, seed=0, num_demos=2)
    assert base.build(episodes, model) == 4
    for other in (
        FeatureCache(tmp_path, sha, seed=1, num_demos=2),
        FeatureCache(tmp_path, sha, seed=0, num_demos=3),
    ):
        assert other.dir != base.dir
        with pytest.raises(FeatureCacheError, match="not cached yet"):
            other.load(ref)
        assert other.build(episodes, model) == 4  # computed for its own key...
        assert meta(other, ref.path)["demos"] != meta(base, ref.path)["demos"]
    assert base.build(episodes, model) == 0  # ...while the first key's files stay valid
    assert (meta(base, ref.path)["seed"], meta(base, ref.path)["num_demos"]) == (0, 2)
    # build(seed=...) re-keys the cache it is called on (the training loop names its seed there)
    rekeyed = FeatureCache(tmp_path, sha)
    assert rekeyed.build(episodes, model, num_demos=2, seed=1) == 0 and rekeyed.seed == 1


def test_a_file_of_another_seed_or_count_is_stale(collection, policy, tmp_path):
    model, sha = policy
    episodes = load_episodes(collection)
    ref = next(e for e in episodes if e.role == "agent_failure")
    source = FeatureCache(tmp_path, sha, seed=0, num_demos=2)
    source.build(episodes, model)
    for key, problem in ((dict(seed=7, num_demos=2), "seed=0"), (dict(num_demos=1), "num_demos=2")):
        copy = FeatureCache(tmp_path, sha, **key)
        copy.dir.mkdir(parents=True, exist_ok=True)
        shutil.copy(source.path_for(ref.path), copy.path_for(ref.path))
        with pytest.raises(FeatureCacheError, match=f"stale cache file \\(made with {problem}"):
            copy.load(ref)


def test_a_cache_being_written_by_another_run_is_waited_for(collection, policy, tmp_path):
    model, sha = policy
    cache, episodes = FeatureCache(tmp_path, sha, seed=0, num_demos=2), load_episodes(collection)
    with folder_lock(cache.dir):
        builder = threading.Thread(target=cache.build, args=(episodes, model))
        builder.start()
        builder.join(timeout=1.0)
        assert builder.is_alive() and [p.name for p in cache.dir.iterdir()] == [LOCK_NAME]
    builder.join(timeout=120)
    assert not builder.is_alive() and cache.build(episodes, model) == 0  # it wrote every shard


def test_bad_keys_and_missing_demonstrations_are_value_errors(collection, policy, tmp_path):
    model, sha = policy
    with pytest.raises(ValueError, match="num_demos=0"):
        FeatureCache(tmp_path, sha, num_demos=0)
    no_demos = [e for e in load_episodes(collection) if e.role != "demo"]
    with pytest.raises(FeatureCacheError, match="environment 0 has no optimal demonstration"):
        FeatureCache(tmp_path, sha).build(no_demos, model)
    assert issubclass(FeatureCacheError, ValueError)  # the command line: one line, status 2

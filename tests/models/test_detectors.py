"""Every registered detector: builds, learns, scores offline == online, saves and loads.

Tiny configs on 32 x 32 frames; policy features are plain tensors (no policy needed).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch
from torch import nn

from aed_models.checkpoint import CheckpointError
from aed_models.detectors import (
    DETECTORS,
    PAPER_PARAMETERS,
    load_detector,
    make_detector,
    save_detector,
)
from tests.helpers import write_synthetic_collection

FIXTURES = Path(__file__).parents[1] / "fixtures"
H = W = 32
DH, DZ = 12, 10
TINY_VISUAL = {"arch": "small_cnn", "feature_dim": 16, "width": 4, "dropout": 0.1}
TINY = {
    "svdd_ed": TINY_VISUAL,
    "taskemb_ed": {**TINY_VISUAL, "hidden_dims": (16,)},
    "lstm_ed": {**TINY_VISUAL, "hidden_dim": 16, "head_dim": 8},
    "dct_ed": {
        **TINY_VISUAL,
        "num_heads": 2,
        "ff_dim": 32,
        "encoder_layers": 1,
        "decoder_layers": 2,
    },
    "probe": {
        "history_dim": DH,
        "task_dim": DZ,
        "hidden_dim": 16,
        "embed_dim": 8,
        "triplets_per_rollout": 4,
    },
    "rnd_oe": {
        "history_dim": DH,
        "hidden_dim": 16,
        "out_dim": 8,
        "time_bin": 2,
        "max_steps": 12,
        "baseline_steps": 3,
    },
}


def tiny(name: str):
    torch.manual_seed(0)
    return make_detector(name, **TINY[name])


def make_batch(seed: int = 0) -> tuple[dict, tuple[torch.Tensor, torch.Tensor]]:
    """One environment: 2 demos, 2 successes + 2 failures of different lengths, and features.

    Error frames are brighter and their history features shifted, so there is something to learn.
    """
    g = torch.Generator().manual_seed(seed)
    lengths = torch.tensor([7, 5, 8, 6])
    b, t = len(lengths), int(lengths.max())
    mask = torch.arange(t)[None] < lengths[:, None]
    is_failure = torch.tensor([False, False, True, True])
    labels = torch.zeros(b, t)
    labels[2, 3:8] = 1.0
    labels[3, 2:6] = 1.0
    frames = torch.rand(b, t, 4, H, W, generator=g) * 0.5 + labels[..., None, None, None] * 0.5
    frames = frames * mask[..., None, None, None]
    history = torch.randn(b, t, DH, generator=g) + 2.0 * labels[..., None]
    task = torch.randn(1, 1, DZ, generator=g).expand(b, t, DZ).clone()
    demo_lengths = torch.tensor([5, 4])
    demo_mask = torch.arange(5)[None] < demo_lengths[:, None]
    demos = {
        "frames": torch.rand(2, 5, 4, H, W, generator=g) * 0.5 * demo_mask[..., None, None, None],
        "mask": demo_mask,
        "lengths": demo_lengths,
    }
    rollouts = {
        "frames": frames,
        "mask": mask,
        "lengths": lengths,
        "labels": labels,
        "is_failure": is_failure,
    }
    return {"demos": demos, "rollouts": rollouts}, (history, task)


@pytest.mark.parametrize("name", sorted(DETECTORS))
def test_training_lowers_the_loss(name):
    detector = tiny(name)
    batch, features = make_batch()
    optimiser = torch.optim.Adam(detector.parameters(), lr=3e-3)

    def eval_loss() -> float:
        detector.eval()
        with torch.no_grad():
            torch.manual_seed(1)
            return float(detector.loss(batch, features)[0])

    before = eval_loss()
    detector.train()
    for _ in range(15):
        loss, parts = detector.loss(batch, features)
        assert torch.isfinite(loss) and parts
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    assert eval_loss() < before


@pytest.mark.parametrize("name", sorted(DETECTORS))
def test_offline_scores_equal_online_steps(name):
    detector = tiny(name).eval()
    batch, (history, task) = make_batch(seed=3)
    rollouts, demos = batch["rollouts"], batch["demos"]
    offline = detector.score(rollouts, demos, (history, task))
    assert offline.shape == rollouts["mask"].shape
    assert (offline[~rollouts["mask"]] == 0).all()
    prepared = detector.prepare(demos)  # the demonstrations read once, for every rollout
    torch.testing.assert_close(detector.score(rollouts, prepared, (history, task)), offline)
    for i, length in enumerate(rollouts["lengths"].tolist()):
        detector.reset(prepared if i % 2 else demos)
        online = [
            detector.step(rollouts["frames"][i, t], (history[i, t], task[i, t]))
            for t in range(length)
        ]
        torch.testing.assert_close(torch.tensor(online), offline[i, :length], atol=1e-5, rtol=0)


@pytest.mark.parametrize("name", ["svdd_ed", "taskemb_ed", "lstm_ed", "dct_ed", "probe"])
def test_embeddings_are_what_the_last_layer_scores(name):
    """embed() returns (B, T, E): the probability detectors' last Linear maps it to the logits
    of their scores, SVDDED's distance to its centres maps it to its scores."""
    from aed_models.detectors.base import steps_of

    detector = tiny(name).eval()
    batch, features = make_batch(seed=4)
    rollouts, demos = batch["rollouts"], batch["demos"]
    embeddings = detector.embed(rollouts, demos, features)
    mask = rollouts["mask"]
    assert embeddings.shape[:2] == mask.shape and embeddings.shape[2] >= 1
    if name == "svdd_ed":
        rescored = detector.distance(embeddings, steps_of(rollouts, mask), detector.centres(demos))
    else:
        last = [m for m in detector.classifier.modules() if isinstance(m, torch.nn.Linear)][-1]
        rescored = torch.sigmoid(last(embeddings).squeeze(-1))
    scores = detector.score(rollouts, demos, features)
    torch.testing.assert_close(rescored * mask, scores, atol=1e-5, rtol=0)
    torch.testing.assert_close(
        detector.embed(rollouts, detector.prepare(demos), features), embeddings
    )


def test_demonstrations_prepared_by_another_detector_are_refused():
    batch, features = make_batch()
    other = tiny("dct_ed").prepare(batch["demos"])
    with pytest.raises(ValueError, match="svdd_ed: demonstrations prepared by another detector"):
        tiny("svdd_ed").score(batch["rollouts"], other, features)


def test_a_detector_without_a_classifier_says_it_has_no_embedding():
    batch, features = make_batch()
    with pytest.raises(NotImplementedError, match="rnd_oe: no classifier"):
        tiny("rnd_oe").eval().embed(batch["rollouts"], batch["demos"], features)


@pytest.mark.parametrize("name", sorted(DETECTORS))
def test_checkpoint_round_trip_and_refusal(name, tmp_path):
    detector = tiny(name).eval()
    batch, features = make_batch()
    path = tmp_path / f"{name}.pt"
    save_detector(path, detector, extra={"task": "PressButton"})
    loaded = load_detector(path)
    assert type(loaded) is type(detector) and loaded.config == detector.config
    assert loaded.checkpoint_extra["task"] == "PressButton"
    torch.testing.assert_close(
        loaded.score(batch["rollouts"], batch["demos"], features),
        detector.score(batch["rollouts"], batch["demos"], features),
    )
    other = "probe" if name != "probe" else "lstm_ed"
    with pytest.raises(CheckpointError, match=f"{name}.*expected '{other}'"):
        load_detector(path, name=other)


def test_dct_ed_checkpoint_of_the_old_layout_loads_and_scores_the_same():
    """The fixture: a TINY DCTED after 3 Adam steps on make_batch(), saved at d69a1b6 (its own
    attention blocks, keys `...attn.query.weight`), with its scores of make_batch(seed=3)."""
    from aed_models.checkpoint import load_checkpoint

    path = FIXTURES / "dct_ed_before_shared_attention.pt"
    old_keys = load_checkpoint(path, family="detector").state_dict
    assert any(".self_attn.query." in k for k in old_keys)
    assert any(".cross_attn.value." in k for k in old_keys)
    assert any(".attn.key." in k for k in old_keys)
    detector = load_detector(path, name="dct_ed")
    assert not any(k.endswith(("query.weight", "key.weight")) for k in detector.state_dict())
    batch, features = make_batch(seed=3)
    scores = detector.score(batch["rollouts"], batch["demos"], features)
    torch.testing.assert_close(
        scores, torch.tensor(detector.checkpoint_extra["scores"]), atol=1e-6, rtol=0
    )
    fresh = tiny("dct_ed").eval()
    assert not torch.allclose(fresh.score(batch["rollouts"], batch["demos"], features), scores)
    fresh.load_state_dict(old_keys)  # resuming training reads the old layout too
    torch.testing.assert_close(fresh.score(batch["rollouts"], batch["demos"], features), scores)


def test_registry_errors_and_profiles():
    with pytest.raises(ValueError, match="known.*probe"):
        make_detector("nope")
    with pytest.raises(ValueError, match="unknown config fields"):
        make_detector("probe", not_a_field=1)
    with pytest.raises(ValueError, match="hidden_dim=0"):
        make_detector("probe", hidden_dim=0)
    with pytest.raises(ValueError, match="profile"):
        DETECTORS.preset("probe", "huge")
    assert set(PAPER_PARAMETERS) == set(DETECTORS) - {"rnd_oe"}
    for name in DETECTORS:
        assert (
            DETECTORS.preset(name, "mini") is not None
            and DETECTORS.preset(name, "paper") is not None
        )


def test_interface_attributes():
    kinds = {name: make_detector(name, **TINY[name]) for name in DETECTORS}
    assert {n for n, d in kinds.items() if d.requires_policy} == {"probe", "rnd_oe"}
    assert {n for n, d in kinds.items() if d.output == "distance"} == {"svdd_ed", "rnd_oe"}
    assert {n for n, d in kinds.items() if d.trains_on == "successes"} == {"svdd_ed", "rnd_oe"}
    assert {n for n, d in kinds.items() if d.memoryless} == {"svdd_ed", "taskemb_ed", "rnd_oe"}


def test_step_before_reset_and_missing_inputs_fail_clearly():
    probe = tiny("probe")
    with pytest.raises(RuntimeError, match="reset"):
        probe.step(None, (torch.zeros(DH), torch.zeros(DZ)))
    probe.reset()
    with pytest.raises(ValueError, match="policy's features"):
        probe.step(None, None)
    with pytest.raises(ValueError, match="history_dim"):
        probe.step(None, (torch.zeros(DH + 1), torch.zeros(DZ)))
    lstm = tiny("lstm_ed")
    lstm.reset()
    with pytest.raises(ValueError, match="reads frames"):
        lstm.step(None)
    with pytest.raises(ValueError, match="demonstrations"):
        tiny("dct_ed").reset(None)


@pytest.mark.parametrize("name", ["svdd_ed", "taskemb_ed", "lstm_ed", "dct_ed"])
def test_visual_detectors_name_what_is_wrong_with_a_batch(name):
    """The shared batch check (`aed_models.nn.batch.check_sequences`) on rollouts and demos."""
    batch, _ = make_batch()
    rollouts, demos = batch["rollouts"], batch["demos"]
    detector = tiny(name).eval()
    with pytest.raises(KeyError, match="no 'mask'"):
        detector.score({"frames": rollouts["frames"]}, demos)
    short_mask = {**rollouts, "mask": rollouts["mask"][:, :3]}
    with pytest.raises(ValueError, match=r"rollouts\['mask'\] of shape \(4, 3\)"):
        detector.score(short_mask, demos)
    with pytest.raises(ValueError, match=r"rollouts\['frames'\] of shape"):
        detector.score({**rollouts, "frames": rollouts["frames"][:, :, :3]}, demos)
    if name != "lstm_ed":  # LSTMED reads no demonstrations
        empty = {**demos, "mask": torch.zeros_like(demos["mask"])}
        with pytest.raises(ValueError, match=f"{name} demos: every sequence needs"):
            detector.score(rollouts, empty)
        with pytest.raises(ValueError, match=f"{name} needs demonstrations"):
            detector.reset(None)


def test_probe_switches():
    batch, features = make_batch()
    naive = make_detector(
        "probe", **{**TINY["probe"], "use_pattern_extractor": False, "lambda_tem": 0.0}
    )
    _, parts = naive.loss(batch, features)
    assert set(parts) == {"cls", "pat"}
    only_tem = make_detector("probe", **{**TINY["probe"], "lambda_cls": 0.0, "lambda_pat": 0.0})
    _, parts = only_tem.loss(batch, features)
    assert set(parts) == {"tem"} and parts["tem"] > 0
    with pytest.raises(ValueError, match="all 0"):
        make_detector("probe", lambda_cls=0.0, lambda_pat=0.0, lambda_tem=0.0)


def test_svdd_has_no_trainable_bias():
    detector = tiny("svdd_ed")
    biases = [n for n, p in detector.named_parameters() if n.endswith("bias")]
    assert biases and all(not detector.get_parameter(n).requires_grad for n in biases)


def test_svdd_variance_floor_penalises_a_collapsed_embedding():
    batch, _ = make_batch()
    detector = tiny("svdd_ed").eval()
    _, spread = detector.loss(batch)
    same = {
        **batch,
        "rollouts": {
            **batch["rollouts"],
            "frames": batch["rollouts"]["frames"][:1, :1]
            .expand_as(batch["rollouts"]["frames"])
            .clone(),
        },
    }
    _, collapsed = detector.loss(same)  # every frame the same: zero variance, the floor's maximum
    assert (
        collapsed["variance_floor"] > 0.95
        and spread["variance_floor"] < collapsed["variance_floor"]
    )
    assert (
        "variance_floor"
        not in make_detector("svdd_ed", **TINY["svdd_ed"], variance_weight=0.0).loss(batch)[1]
    )


def test_svdd_aligned_centres_follow_the_demonstrations_in_time():
    from aed_models.nn import encode_frames

    batch, _ = make_batch()
    demos = batch["demos"]  # lengths 5 and 4
    detector = tiny("svdd_ed").eval()
    with torch.no_grad():
        z = encode_frames(detector.encoder, demos["frames"], demos["mask"])
        centres = detector.centres(demos)
        assert centres.shape == (5, z.shape[-1])
        torch.testing.assert_close(centres[2], (z[0, 2] + z[1, 2]) / 2)
        torch.testing.assert_close(
            centres[4], (z[0, 4] + z[1, 3]) / 2
        )  # the shorter one is held at its end
        # subsampled demonstrations (training): each contributes its latest kept frame at or
        # before t
        kept = {
            **demos,
            "source": torch.tensor([[0, 2, 4, 0, 0], [0, 3, 0, 0, 0]]),
            "mask": torch.tensor(
                [[True, True, True, False, False], [True, True, False, False, False]]
            ),
        }
        sub = detector.centres(kept)
        zk = encode_frames(detector.encoder, demos["frames"], kept["mask"])
        torch.testing.assert_close(sub[1], (zk[0, 0] + zk[1, 0]) / 2)
        torch.testing.assert_close(sub[3], (zk[0, 1] + zk[1, 1]) / 2)
        torch.testing.assert_close(sub[4], (zk[0, 2] + zk[1, 1]) / 2)
        # the distance takes the nearest centre within `window` steps (rollouts run at their
        # own pace)
        step2 = torch.tensor([2])
        assert float(detector.distance(centres[3][None], step2, centres)) == 0.0  # tiny window: 10
        exact = make_detector("svdd_ed", **TINY["svdd_ed"], window=0)
        assert float(exact.distance(centres[3][None], step2, centres)) > 0.0
        torch.testing.assert_close(
            exact.distance(centres[4][None], torch.tensor([9]), centres), torch.zeros(1)
        )  # past the end: the last
        single = make_detector("svdd_ed", **TINY["svdd_ed"], centre="all")
        single.load_state_dict(detector.state_dict())
        torch.testing.assert_close(
            single.eval().centres(demos), z[demos["mask"]].mean(0, keepdim=True)
        )
    with pytest.raises(ValueError, match="centre='middle'"):
        make_detector("svdd_ed", centre="middle")
    with pytest.raises(ValueError, match="window=-1"):
        make_detector("svdd_ed", window=-1)


@pytest.mark.parametrize("name", ["svdd_ed", "taskemb_ed", "rnd_oe"])
def test_detectors_without_memory_score_the_running_max_of_their_frames(name):
    """The protocol's post-processing: batched and online, the running maximum of `score`."""
    from aed_models.detectors.postprocess import OnlinePostprocess, postprocess

    batch, features = make_batch()
    rollouts, demos = batch["rollouts"], batch["demos"]
    detector = tiny(name).eval()
    raw = detector.score(rollouts, demos, features)
    scores = postprocess(detector, raw, rollouts["mask"])
    assert not torch.equal(raw, scores)  # the frames' scores are not already sorted
    online = OnlinePostprocess(detector)
    for i, length in enumerate(rollouts["lengths"].tolist()):
        torch.testing.assert_close(scores[i, :length], torch.cummax(raw[i, :length], 0).values)
        detector.reset(demos)
        online.reset()
        steps = [
            online(detector.step(rollouts["frames"][i, t], (features[0][i, t], features[1][i, t])))
            for t in range(length)
        ]
        torch.testing.assert_close(torch.tensor(steps), scores[i, :length], atol=1e-5, rtol=0)
    assert (scores[~rollouts["mask"]] == 0).all()


@pytest.mark.parametrize("name", ["lstm_ed", "dct_ed", "probe"])
def test_detectors_with_memory_are_not_post_processed(name):
    from aed_models.detectors.postprocess import OnlinePostprocess, postprocess

    batch, features = make_batch()
    detector = tiny(name).eval()
    raw = detector.score(batch["rollouts"], batch["demos"], features)
    assert postprocess(detector, raw, batch["rollouts"]["mask"]) is raw
    online = OnlinePostprocess(detector)
    assert [online(x) for x in (0.5, 0.2, 0.7)] == [0.5, 0.2, 0.7]


@pytest.mark.parametrize("name", ["svdd_ed", "taskemb_ed", "rnd_oe"])
def test_checkpoints_with_the_running_max_option_load_or_say_why_not(name, tmp_path):
    """`running_max` was a config field of the memoryless detectors before the post-processing
    step: True (the default) loads as today's config, False (per-frame scores) is refused."""
    from aed_models.checkpoint import save_checkpoint

    detector = tiny(name).eval()
    for value in (True, False):
        path = tmp_path / f"{name}_{value}.pt"
        save_checkpoint(
            path,
            family="detector",
            name=name,
            config={**detector.config.to_dict(), "running_max": value},
            state_dict=detector.state_dict(),
        )
        if value:
            assert load_detector(path).config == detector.config
        else:
            with pytest.raises(CheckpointError, match="running_max=False.*running maximum"):
                load_detector(path)
    with pytest.raises(ValueError, match="unknown config fields.*running_max"):
        make_detector(name, running_max=True)


# -- training loop and feature cache on a tiny synthetic collection (no simulation) -----------


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    """Two environments; per env 3 demos, 3 successes, 3 failures (tests/test_data.py's
    episodes)."""
    counts = {"demo": 3, "agent_success": 3, "agent_failure": 3}
    return write_synthetic_collection(tmp_path_factory.mktemp("collection"), counts, steps=12)


@pytest.fixture(scope="module")
def tiny_policy(tmp_path_factory):
    from aed_models.nn import VisualHeadConfig
    from aed_models.policies import POLICIES, make_policy, save_policy

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
    return path


def test_train_detector_checkpoints_and_resumes(collection, tmp_path):
    from aed_models.train.common import check_same_training
    from aed_models.train.detector import TrainDetectorConfig, train_detector

    config = make_detector("lstm_ed", **TINY["lstm_ed"]).config
    cfg = TrainDetectorConfig.from_preset(
        task="PickPlace",
        detector="lstm_ed",
        data=collection,
        out=tmp_path,
        epochs=1,
        num_envs=1,
        max_frames=6,
        progress=False,
    )
    first = load_detector(train_detector(cfg, config))
    assert first.checkpoint_extra["task"] == "PickPlace" and len(first.checkpoint_extra["log"]) == 1
    cfg2 = TrainDetectorConfig.from_preset(
        task="PickPlace",
        detector="lstm_ed",
        data=collection,
        out=tmp_path,
        epochs=2,
        num_envs=1,
        max_frames=6,
        progress=False,
    )
    second = load_detector(train_detector(cfg2, config))
    log = second.checkpoint_extra["log"]
    assert [e["epoch"] for e in log] == [1, 2] and log[0] == first.checkpoint_extra["log"][0]
    with pytest.raises(ValueError, match="policy=None"):
        TrainDetectorConfig.from_preset(detector="probe")
    changed = dataclasses.replace(cfg2, epochs=3, lr=1e-3)
    with pytest.raises(ValueError, match="trained with lr=0.0003, this run asks 0.001"):
        train_detector(changed, config)
    assert cfg2.precision == "bf16"  # mini's LSTMED: bfloat16 autocast
    with pytest.raises(ValueError, match="trained with precision='bf16', this run asks 'fp32'"):
        train_detector(dataclasses.replace(cfg2, epochs=3, precision="fp32"), config)
    # a checkpoint written before the field existed trained in float32: not resumed under bf16
    then = {"train_config": {"task": "PickPlace"}, "data_key": "k"}
    check_same_training(tmp_path / "last.pt", then, {"precision": "fp32"}, "k")
    with pytest.raises(ValueError, match="trained with precision='fp32', this run asks 'bf16'"):
        check_same_training(tmp_path / "last.pt", then, {"precision": "bf16"}, "k")
    with pytest.raises(ValueError, match="episodes of PickPlace, not of task='PressButton'"):
        train_detector(
            dataclasses.replace(cfg2, task="PressButton", out=tmp_path / "other"), config
        )
    other = make_detector("lstm_ed", **{**TINY["lstm_ed"], "head_dim": 9}).config
    with pytest.raises(ValueError, match="another lstm_ed detector config"):
        train_detector(
            TrainDetectorConfig.from_preset(
                task="PickPlace",
                detector="lstm_ed",
                data=collection,
                out=tmp_path,
                epochs=3,
                num_envs=1,
                max_frames=6,
                progress=False,
            ),
            other,
        )


def test_train_detector_config_profiles_and_composition(collection):
    from aed_models.data import Composition, load_episodes
    from aed_models.train.detector import TrainDetectorConfig, build_dataset

    mini, paper = (
        TrainDetectorConfig.from_preset(detector="lstm_ed"),
        TrainDetectorConfig.from_preset(detector="lstm_ed", profile="paper"),
    )
    assert (mini.lr, mini.weight_decay, paper.lr, paper.weight_decay) == (3e-4, 0.0, 1e-4, 1e-2)
    assert (mini.composition, mini.epochs, mini.num_envs, paper.composition) == (
        (3, 4, 4),
        30,
        0,
        (5, 10, 10),
    )
    single = TrainDetectorConfig.from_preset(detector="taskemb_ed")
    assert (single.max_frames, single.epochs, mini.max_frames) == (
        8,
        150,
        0,
    )  # temporal detectors: every frame
    assert TrainDetectorConfig.from_preset(detector="probe", policy="dct").composition == (
        5,
        10,
        10,
    )  # cached features: the paper's
    demo = TrainDetectorConfig.from_preset(detector="svdd_ed", profile="demo")
    assert (demo.epochs, demo.composition, demo.max_frames) == (4, (3, 4, 3), 8)
    episodes = load_episodes(collection)
    for name, expected in (("lstm_ed", Composition(2, 3, 1)), ("svdd_ed", Composition(2, 4, 0))):
        cfg = TrainDetectorConfig.from_preset(detector=name, data=collection, composition=(2, 3, 1))
        assert build_dataset(cfg, name, episodes, None, "").composition == expected
    with pytest.raises(ValueError, match="composition"):
        TrainDetectorConfig.from_preset(detector="lstm_ed", composition=(0, 3, 1))


def test_probe_trains_on_cached_features(collection, tiny_policy, tmp_path):
    from aed_models.checkpoint import file_sha256
    from aed_models.train.detector import TrainDetectorConfig, train_detector

    config = make_detector("probe", **TINY["probe"]).config  # feature sizes come from the policy
    cfg = TrainDetectorConfig.from_preset(
        task="PickPlace",
        detector="probe",
        policy=str(tiny_policy),
        data=collection,
        out=tmp_path / "probe",
        epochs=1,
        progress=False,
    )
    detector = load_detector(train_detector(cfg, config))
    extra = detector.checkpoint_extra
    assert extra["policy_name"] == "naive_dc" and extra["policy_sha256"] == file_sha256(tiny_policy)
    assert detector.config.history_dim != DH  # taken from the policy
    key_dir = tmp_path / "probe" / "features" / extra["policy_sha256"][:16] / "seed0-demos5"
    cached = list(key_dir.glob("*.npz"))
    assert sorted(p.stem for p in cached) == sorted(
        f"{role}_env{e:03d}_0000" for role in ("agent_success", "agent_failure") for e in (0, 1)
    )


def test_feature_cache_detects_stale_and_corrupt_files(collection, tiny_policy, tmp_path):
    from aed_models.checkpoint import file_sha256
    from aed_models.data import load_episodes
    from aed_models.policies import load_policy
    from aed_models.train.feature_cache import FeatureCache, FeatureCacheError

    episodes = load_episodes(collection)
    policy, sha = load_policy(tiny_policy), file_sha256(tiny_policy)
    cache = FeatureCache(tmp_path, sha)
    assert cache.build(episodes, policy) == 4 and cache.build(episodes, policy) == 0
    ref = next(e for e in episodes if e.role == "agent_failure")
    ep = cache.load(ref)
    assert ep.history.shape == (ref.num_frames, policy.history_dim) and ep.labels.max() == 1.0

    cache.path_for(ref.path).write_bytes(b"not a zip file")
    with pytest.raises(FeatureCacheError, match="corrupt"):
        FeatureCache(tmp_path, sha).load(ref)
    with pytest.raises(FeatureCacheError, match="not cached"):
        FeatureCache(tmp_path, "0" * 64).load(ref)
    assert cache.build(episodes, policy) == 1  # only the corrupt shard is recomputed
    # a cache file copied in from another policy is stale, not silently used
    other = FeatureCache(tmp_path, "f" * 16 + sha[16:])
    other.dir.mkdir(parents=True, exist_ok=True)
    other.path_for(ref.path).write_bytes(cache.path_for(ref.path).read_bytes())
    with pytest.raises(FeatureCacheError, match="stale"):
        other.load(ref)


def test_feature_iterations_follow_the_frame_iterations(collection, tiny_policy, tmp_path):
    from aed_models.augment import RolloutAugment
    from aed_models.checkpoint import file_sha256
    from aed_models.data import EnvironmentIterations, load_episodes
    from aed_models.policies import load_policy
    from aed_models.train.feature_cache import FeatureCache, FeatureIterations

    episodes = load_episodes(collection)
    cache = FeatureCache(tmp_path, file_sha256(tiny_policy))
    cache.build(episodes, load_policy(tiny_policy))
    feats = FeatureIterations(
        episodes, cache, "detector", augment=RolloutAugment(), max_frames=10, seed=5
    )
    frames = EnvironmentIterations(
        episodes, "detector", augment=RolloutAugment(), max_frames=10, seed=5
    )
    for item in [(0, 0), (3, 1)]:
        a, b = feats[item], frames[item]
        for key in ("lengths", "labels", "mask", "is_failure"):
            assert torch.equal(a["rollouts"][key], b["rollouts"][key]), key
        history, task = a["features"]
        assert (
            history.shape[:2] == a["rollouts"]["mask"].shape
            and (history[~a["rollouts"]["mask"]] == 0).all()
        )


def test_rnd_oe_calibrates_errors_by_the_training_successes_at_each_step():
    """One bias-corrected update: each bin's scale is the mean success error in that bin, so
    calibrated success errors average 1 per bin; bins no success reached take the bin before."""
    rnd = make_detector("rnd_oe", **{**TINY["rnd_oe"], "baseline_steps": 0})  # per-frame score
    batch, features = make_batch()
    rollouts = batch["rollouts"]
    assert float(rnd.error_scale) == 1.0 and (rnd.time_scale == 1.0).all()  # untrained: raw errors
    rnd.train()
    loss, _ = rnd.loss(batch, features)
    rnd.eval()
    assert float(rnd.error_scale) == pytest.approx(float(loss.detach()), rel=1e-6)
    scores = rnd.score(rollouts, batch["demos"], features)
    successes = rollouts["mask"] & ~rollouts["is_failure"][:, None]
    bins = torch.arange(scores.shape[1]).expand_as(scores) // 2
    for b in bins[successes].unique().tolist():
        assert scores[successes & (bins == b)].mean().item() == pytest.approx(1.0, rel=1e-5), b
    last_seen = int(bins[successes].max())  # successes of 7 and 5 frames: steps 0-6, bins 0-3
    assert (rnd.time_scale[last_seen:] == rnd.time_scale[last_seen]).all()
    assert rnd.time_scale[:last_seen].unique().numel() == last_seen


def test_rnd_oe_scores_the_running_max_of_errors_over_the_rollouts_own_start():
    from aed_models.detectors.postprocess import OnlinePostprocess, postprocess

    rnd = tiny("rnd_oe")
    batch, features = make_batch()
    rnd.train()
    rnd.loss(batch, features)  # a trained time calibration, so that online meets it too
    rnd.eval()
    rollouts, k = batch["rollouts"], rnd.config.baseline_steps
    calibrated = rnd.calibrated(
        features[0], torch.arange(rollouts["mask"].shape[1]).expand_as(rollouts["mask"])
    )
    scores = postprocess(rnd, rnd.score(rollouts, batch["demos"], features), rollouts["mask"])
    online_max = OnlinePostprocess(rnd)
    for i, length in enumerate(rollouts["lengths"].tolist()):
        c = calibrated[i, :length].tolist()
        ratios = [c[t] / (sum(c[: min(t + 1, k)]) / min(t + 1, k)) for t in range(length)]
        expected = torch.tensor([max(ratios[: t + 1]) for t in range(length)])
        torch.testing.assert_close(scores[i, :length], expected, atol=1e-5, rtol=1e-5)
        rnd.reset(batch["demos"])
        online_max.reset()
        online = [
            online_max(rnd.step(None, (features[0][i, t], features[1][i, t])))
            for t in range(length)
        ]
        torch.testing.assert_close(torch.tensor(online), scores[i, :length], atol=1e-5, rtol=0)
    assert (scores[:, 1:] >= scores[:, :-1])[rollouts["mask"][:, 1:]].all()
    with pytest.raises(ValueError, match="time_bin"):
        make_detector("rnd_oe", time_bin=-1)


def test_rnd_oe_whitens_its_inputs_with_the_statistics_of_every_training_frame():
    """Running input statistics merged batch by batch equal those of all frames at once."""
    rnd = tiny("rnd_oe")
    torch.manual_seed(0)
    batches = [torch.randn(n, DH) * 3 + 1 for n in (5, 11, 2)]
    for b in batches:
        rnd.update_input_stats(b)
    every = torch.cat(batches)
    assert float(rnd.input_count) == len(every)
    assert torch.allclose(rnd.input_mean, every.mean(0), atol=1e-5)
    assert torch.allclose(rnd.input_var, every.var(0, unbiased=False), atol=1e-4)
    whitened = rnd._whiten(every)
    assert torch.allclose(whitened.mean(0), torch.zeros(DH), atol=1e-4)
    assert whitened.abs().max() <= rnd.config.input_clip


def test_aed_models_lists_paper_counts_and_explains_each_difference():
    from aed_eval.models import format_rows, model_rows

    rows = model_rows("paper")
    for row in rows:
        if row.paper:
            assert abs(row.parameters - row.paper) / row.paper < 0.2, row
            off = abs(row.parameters - row.paper) / row.paper > 0.001
            assert bool(row.note) or not off, (
                f"{row.name}: {row.parameters} vs the paper's {row.paper} unexplained"
            )
    assert {r.name for r in rows if r.family == "detector"} == set(DETECTORS)
    text = format_rows(rows, "paper")
    assert (
        "| detector | probe | dct features | 0.69M | 0.65M [2] |" in text
        and "\n[2] probe: " in text
    )


@pytest.mark.parametrize("num_layers", [1, 2])
def test_lstm_step_equals_nn_lstm_step_by_step(num_layers):
    from aed_models.nn import lstm_step

    torch.manual_seed(0)
    lstm = nn.LSTM(6, 5, num_layers=num_layers, batch_first=True).eval()
    x = torch.randn(3, 7, 6)
    expected, (h_n, c_n) = lstm(x)
    state = None
    for t in range(x.shape[1]):
        out, state = lstm_step(lstm, x[:, t], state)
        assert torch.allclose(out, expected[:, t], atol=1e-6)
    assert torch.allclose(state[0], h_n, atol=1e-6) and torch.allclose(state[1], c_n, atol=1e-6)
    with pytest.raises(ValueError, match="expected"):
        lstm_step(lstm, torch.randn(3, 4))


def test_detector_benchmark_runs_every_mini_detector():
    from tests.helpers import load_script

    bench = load_script("bench_detectors")
    cfg = bench.Config(train_iterations=1, rollout_frames=2)
    batch, _ = bench.synthetic_batch(1, 1)
    for name in DETECTORS:
        overrides = (
            {"history_dim": cfg.history_dim, "task_dim": cfg.task_dim} if name == "probe" else {}
        )
        overrides = {"history_dim": cfg.history_dim} if name == "rnd_oe" else overrides
        detector = make_detector(name, DETECTORS.preset(name, "mini"), **overrides)
        t10, t200 = bench.online_latency(detector, batch["demos"], cfg)
        assert t10 > 0 and t200 > 0 and bench.train_throughput(detector, cfg) > 0
        small = bench.Config(horizon=8, demo_frames=4, score_repeats=1)
        assert min(bench.offline_scoring(detector, small)) > 0

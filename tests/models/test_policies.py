"""Demonstration-conditioned policies: shapes, causality, online = batched, masks, checkpoints,
training (loss falls, resume is exact) on small synthetic collections."""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch

from aed_models.checkpoint import CheckpointError, save_checkpoint
from aed_models.nn import VisualHeadConfig
from aed_models.policies import POLICIES, load_policy, make_policy, save_policy
from aed_models.train.common import check_same_training
from aed_models.train.policy import TrainPolicyConfig, prepare, train_policy
from aed_tasks import trajectory
from aed_tasks.episode import Episode
from tests.helpers import load_script, recorded_episode, write_synthetic_collection

H, W = 32, 40
TINY = {
    "naive_dc": {},
    "dct": {"num_heads": 4, "ff_dim": 32, "demo_frames": 6},  # demos of 9, 5, 7 frames: thinned
    "scan": {"lstm_hidden": 12, "attention_dim": 8, "demo_frames": 6},
}


CHUNK = POLICIES.preset("scan", "mini").action_chunk


def tiny_config(name: str, profile: str = "mini"):
    """End to end (the paper's way), without the target localizer (tests/models/test_encoder.py
    trains on a frozen encoder, tests/models/test_localizer.py reads a localizer)."""
    visual = VisualHeadConfig(arch="small_cnn", out_dim=16, width=4, dropout=0.5)
    return POLICIES.preset(
        name,
        profile,
        visual=visual,
        actor_hidden=(16, 8),
        frozen_encoder=False,
        localizer=None,
        subgoal_head="linear",  # the pointer head points at located targets
        **TINY[name],
    )


def tiny_policy(name: str, seed: int = 0, **overrides):
    torch.manual_seed(seed)
    return make_policy(name, tiny_config(name), **overrides)


def sequences(n: int, lengths: list[int], seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    longest = max(lengths)
    frames = torch.rand(n, longest, 4, H, W, generator=g)
    mask = torch.arange(longest)[None] < torch.tensor(lengths)[:, None]
    frames[~mask] = 0.0
    actions = torch.randn(n, longest, 4, generator=g).clamp(-1, 1)
    later = torch.arange(longest)[:, None] + torch.arange(CHUNK)[None]  # consecutive frames
    return {
        "frames": frames,
        "mask": mask,
        "lengths": torch.tensor(lengths),
        "actions": actions,
        "action_chunks": actions[:, later.clamp_max(longest - 1)],
        "chunk_valid": later[None] < (torch.tensor(lengths) - 1)[:, None, None],
        "proprio": torch.rand(n, longest, 5, generator=g) * mask[..., None],
        "subgoal": torch.rand(n, longest, 3, generator=g) * mask[..., None],
    }


@pytest.fixture
def batch():
    return {"demos": sequences(3, [9, 5, 7], seed=1), "rollouts": sequences(2, [12, 8], seed=2)}


@pytest.mark.parametrize("name", list(POLICIES))
def test_forward_backward_shapes_and_input_unchanged(name, batch):
    policy = tiny_policy(name, inverse_dynamics=True, subgoal_weight=1.0)
    before = {k: {kk: vv.clone() for kk, vv in v.items()} for k, v in batch.items()}
    out = policy(batch["rollouts"], batch["demos"])
    assert out["pos"].shape == (2, 12, 3) and out["grip"].shape == (2, 12, 1)
    assert out["history"].shape == (2, 12, policy.history_dim) and out["task"].shape == (
        2,
        12,
        policy.task_dim,
    )
    assert (
        policy.history_dim + policy.task_dim + 3 == policy.actor.body[0].in_features
    )  # + the predicted subgoal offset
    assert out["subgoal"].shape == (2, 12, 3)
    loss, parts = policy.loss(batch)
    loss.backward()
    assert np.isfinite(parts["loss"]) and {
        "pos_mse",
        "grip_loss",
        "grip_acc",
        "inverse_dynamics",
        "subgoal_mse",
    } <= set(parts)
    assert all(p.grad is not None for p in policy.visual.parameters())
    for key, group in batch.items():
        for k, v in group.items():
            assert torch.equal(v, before[key][k]), f"{key}[{k}] was modified"


def test_paper_dims_match_the_papers_table():
    for name, task_dim in (("naive_dc", 512), ("dct", 256), ("scan", 256)):
        config = POLICIES.preset(name, "paper")
        assert config.visual.arch == "resnet18" and config.visual.dropout == 0.5
        policy = make_policy(name, config)
        assert (policy.history_dim, policy.task_dim) == (256, task_dim)
        assert policy.actor.body[0].in_features == 256 + task_dim  # 768 or 512


@pytest.mark.parametrize("name", list(POLICIES))
def test_causal_the_past_ignores_the_future(name, batch):
    policy = tiny_policy(name).eval()
    with torch.no_grad():
        a = policy(batch["rollouts"], batch["demos"])
        changed = {k: v.clone() for k, v in batch["rollouts"].items()}
        changed["frames"][:, 6:] = torch.rand_like(changed["frames"][:, 6:])
        b = policy(changed, batch["demos"])
    for key in ("pos", "grip", "history", "task"):
        assert torch.allclose(a[key][:, :6], b[key][:, :6], atol=1e-5), key
    if name != "naive_dc":
        assert not torch.allclose(a["task"][0, 6:], b["task"][0, 6:])


@pytest.mark.parametrize("name", list(POLICIES))
@pytest.mark.parametrize("subgoal_weight", [0.0, 1.0])
def test_online_features_equal_batched(name, subgoal_weight, batch):
    policy = tiny_policy(name, subgoal_weight=subgoal_weight)
    policy.set_action_stats(torch.randn(50, 4) * 0.2)
    policy.eval()
    rollout, proprio = batch["rollouts"]["frames"][:1], batch["rollouts"]["proprio"][:1]
    with torch.no_grad():
        feats = policy.features(
            rollout, torch.ones(1, 12, dtype=torch.bool), batch["demos"], proprio=proprio
        )
        out = policy({"frames": rollout, "proprio": proprio}, batch["demos"])
    expected = policy.to_action(*policy.ensemble_chunks(out["pos_chunk"], out["grip_chunk"]))[0]
    policy.reset(batch["demos"])
    for t in range(12):
        action = policy.act(rollout[0, t], proprio=proprio[0, t])
        history, task = policy.features()
        assert action.shape == (4,) and action.dtype == np.float32
        assert np.all(np.abs(action) <= 1) and action[3] in (-1.0, 1.0)
        assert torch.allclose(history, feats.history[0, t], atol=1e-5)
        assert torch.allclose(task, feats.task[0, t], atol=1e-5)
        assert np.allclose(action, expected[t].numpy(), atol=1e-4)


def test_act_reads_maniskill_observations():
    policy = tiny_policy("scan")
    rgb = torch.randint(0, 256, (1, H, W, 3), dtype=torch.uint8)
    depth = torch.randint(0, 5000, (1, H, W, 1), dtype=torch.int16)
    frame = torch.cat([rgb[0].permute(2, 0, 1) / 255.0, depth[0].permute(2, 0, 1) / 5000.0])
    tcp_pose, qpos = torch.rand(1, 7), torch.rand(1, 9)
    proprio = torch.cat([tcp_pose[0, :3], qpos[0, -2:]])
    demos = sequences(2, [5, 4], seed=0)
    policy.reset(demos)
    a = policy.act(
        {
            "sensor_data": {"front": {"rgb": rgb, "depth": depth}},
            "extra": {"tcp_pose": tcp_pose},
            "agent": {"qpos": qpos},
        }
    )
    policy.reset(demos)
    assert np.allclose(a, policy.act(frame, proprio=proprio), atol=1e-5)
    with pytest.raises(ValueError, match="sensor_data/front"):
        policy.act({"state": torch.zeros(3)})
    with pytest.raises(ValueError, match="extra/tcp_pose"):
        policy.act({"sensor_data": {"front": {"rgb": rgb, "depth": depth}}})
    with pytest.raises(ValueError, match="proprioception"):
        policy.features(frame[None, None], None, {k: v for k, v in demos.items() if k != "proprio"})
    blind = make_policy("scan", tiny_config("scan"), proprio=False, subgoal_weight=0.0)
    blind.reset({k: v for k, v in demos.items() if k != "proprio"})
    assert blind.act(frame).shape == (4,)
    fresh = tiny_policy("scan")
    with pytest.raises(RuntimeError, match="reset"):
        fresh.act(frame)


@pytest.mark.parametrize("name", list(POLICIES))
def test_padded_demos_give_the_same_task_embedding(name):
    policy = tiny_policy(name).eval()
    demos = sequences(3, [9, 5, 7], seed=4)
    rollout = sequences(1, [6], seed=5)
    one_by_one = []
    with torch.no_grad():
        args = rollout["frames"], rollout["mask"]
        padded = policy.features(*args, demos, proprio=rollout["proprio"]).task
        # the same demos padded further, with junk in the padding
        longer = {
            "frames": torch.cat([demos["frames"], torch.rand(3, 4, 4, H, W)], dim=1),
            "mask": torch.cat([demos["mask"], torch.zeros(3, 4, dtype=torch.bool)], dim=1),
            "proprio": torch.cat([demos["proprio"], torch.rand(3, 4, 5)], dim=1),
        }
        longer["frames"][:, :9][~demos["mask"]] = torch.rand(int((~demos["mask"]).sum()), 4, H, W)
        longer["proprio"][:, :9][~demos["mask"]] = torch.rand(int((~demos["mask"]).sum()), 5)
        assert torch.allclose(
            policy.features(*args, longer, proprio=rollout["proprio"]).task, padded, atol=1e-5
        )
        if name == "naive_dc":  # the mean over demos of per-demo embeddings: check each unpadded
            for i, n in enumerate([9, 5, 7]):
                one = {
                    "frames": demos["frames"][i : i + 1, :n],
                    "proprio": demos["proprio"][i : i + 1, :n],
                }
                one_by_one.append(policy.features(*args, one, proprio=rollout["proprio"]).task)
            assert torch.allclose(torch.stack(one_by_one).mean(0), padded, atol=1e-5)


@pytest.mark.parametrize("name", list(POLICIES))
def test_save_load_round_trip(name, batch, tmp_path):
    policy = tiny_policy(name)
    policy.set_action_stats(torch.randn(40, 4))
    save_policy(tmp_path / "p.pt", policy, extra={"epoch": 1})
    loaded = load_policy(tmp_path / "p.pt")
    assert type(loaded) is type(policy) and loaded.config == policy.config
    assert torch.equal(loaded.action_std, policy.action_std)
    policy.eval()
    with torch.no_grad():
        a, b = policy(batch["rollouts"], batch["demos"]), loaded(batch["rollouts"], batch["demos"])
    assert torch.equal(a["pos"], b["pos"]) and torch.equal(a["task"], b["task"])


def test_wrong_checkpoints_and_names_are_clear_errors(tmp_path):
    save_policy(tmp_path / "dct.pt", tiny_policy("dct"))
    with pytest.raises(
        CheckpointError, match="dct.pt: a policy checkpoint of 'dct', expected 'scan'"
    ):
        load_policy(tmp_path / "dct.pt", name="scan")
    save_checkpoint(tmp_path / "det.pt", family="detector", name="probe", config={}, state_dict={})
    with pytest.raises(
        CheckpointError, match="det.pt: a 'detector' checkpoint, expected a 'policy' one"
    ):
        load_policy(tmp_path / "det.pt")
    config = tiny_config("dct").to_dict()
    save_checkpoint(
        tmp_path / "bad.pt",
        family="policy",
        name="dct",
        config=config,
        state_dict={"w": torch.ones(1)},
    )
    with pytest.raises(CheckpointError, match="bad.pt: does not fit policy 'dct'"):
        load_policy(tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="unknown policy 'bc'; known: naive_dc, dct, scan"):
        make_policy("bc")
    with pytest.raises(ValueError, match="num_heads=5"):
        POLICIES.preset("dct", "mini", num_heads=5)
    with pytest.raises(ValueError, match="actor_hidden"):
        POLICIES.preset("scan", "mini", actor_hidden=())


# --- training on a synthetic collection (no simulation) --------------------------------------


def synthetic(
    role: str, env_index: int, seed: int, steps: int
) -> tuple[Episode, trajectory.RecordedSteps]:
    """Frame t shows a white bar at a random column b_t * (W - 8); the action is a function of
    b_t: x = 2 b - 1, y = 1 - 2 b, z = 0, gripper open when b > 0.5. A policy that reads its
    frame can learn it."""
    rng = np.random.default_rng(seed)
    b = rng.uniform(0.0, 1.0, steps + 1)
    rgb = np.zeros((steps + 1, H, W, 3), np.uint8)
    for t, column in enumerate(np.round(b * (W - 8)).astype(int)):
        rgb[t, :, column : column + 8] = 255
    depth = np.full((steps + 1, H, W, 1), 500 + 10 * env_index, np.int16)
    actions = np.stack(
        [2 * b - 1, 1 - 2 * b, np.zeros_like(b), np.where(b > 0.5, 1.0, -1.0)], axis=1
    )[:steps]
    tcp_pose = np.tile(np.float32([0.1, 0.0, 0.2, 1, 0, 0, 0]), (steps + 1, 1))
    return recorded_episode("PressButton", role, env_index, seed, rgb, depth, actions, tcp_pose)


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> Path:
    """Four environments; per env 2 demos and 4 agent successes of 8..14 steps."""
    return write_synthetic_collection(
        tmp_path_factory.mktemp("policy_data"),
        {"demo": 2, "agent_success": 4},
        envs=(0, 1, 2, 3),
        steps=8,
        make_episode=synthetic,
        demo_seed_offset=10,
    )


def train_config(collection: Path, out: Path, **kw) -> TrainPolicyConfig:
    base = {
        "task": "PressButton",
        "data": collection,
        "out": out,
        "progress": False,
        "shift": 2,  # end to end: frames are shifted, there are no cached features to drop
        "feature_dropout": 0.0,
    }
    return TrainPolicyConfig.from_preset(**{**base, **kw})


def test_training_loss_falls(collection, tmp_path):
    cfg = train_config(collection, tmp_path / "run", policy="naive_dc", epochs=6, lr=3e-3)
    config = tiny_config("naive_dc")
    config.visual.dropout = 0.0
    config.action_chunk = 1  # each synthetic frame's action is its own: later ones are noise
    final = train_policy(cfg, config)
    log = json.loads((tmp_path / "run" / "train_log.json").read_text())
    assert [e["epoch"] for e in log] == list(range(1, 7))
    assert log[-1]["pos_mse"] < 0.7 * log[0]["pos_mse"], log
    policy = load_policy(final)
    assert not policy.training and torch.allclose(policy.action_mean[2], torch.tensor(0.0))


def test_num_successes_keeps_each_environments_first_agent_successes(collection, tmp_path):
    from aed_models.train.common import select_successes, task_episodes

    episodes = task_episodes(collection, 0)
    kept = select_successes(episodes, 3)
    successes = [e for e in kept if e.role == "agent_success"]
    assert sorted(Counter(e.env_index for e in successes).values()) == [3, 3, 3, 3]
    assert {e.traj for e in successes} == {"traj_0", "traj_1", "traj_2"}
    assert [e for e in kept if e.role == "demo"] == [e for e in episodes if e.role == "demo"]
    assert select_successes(episodes, 0) == episodes == select_successes(episodes, 99)
    with pytest.raises(ValueError, match="num_successes=-1: must be >= 0"):
        train_config(collection, tmp_path / "x", num_successes=-1)
    train_policy(
        train_config(collection, tmp_path / "run", policy="dct", epochs=1, num_successes=2),
        tiny_config("dct"),
    )
    with pytest.raises(ValueError, match="trained with num_successes=2, this run asks 4"):
        train_policy(
            train_config(collection, tmp_path / "run", policy="dct", epochs=2, num_successes=4),
            tiny_config("dct"),
        )
    # the lever table reads what each checkpoint trained on (the collection as its "rollouts")
    table = load_script("lever_table")
    spec = f"two={tmp_path / 'run' / 'policy.pt'}:{collection}"
    rows = table.main(table.Config(baseline=spec, out=tmp_path / "t.json"))
    assert rows[0]["successes_per_env"] == [2] and rows[0]["train_envs"] == 4
    assert rows[0]["only_baseline"] == rows[0]["only_this"] == 0
    assert json.loads((tmp_path / "t.json").read_text())["rows"] == rows


def test_resume_gives_the_same_weights(collection, tmp_path):
    whole = train_policy(
        train_config(collection, tmp_path / "whole", policy="dct", epochs=3, num_envs=2),
        tiny_config("dct"),
    )
    train_policy(
        train_config(collection, tmp_path / "split", policy="dct", epochs=1, num_envs=2),
        tiny_config("dct"),
    )
    resumed = train_policy(
        train_config(collection, tmp_path / "split", policy="dct", epochs=3, num_envs=2),
        tiny_config("dct"),
    )
    a, b = load_policy(whole).state_dict(), load_policy(resumed).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    log = json.loads((tmp_path / "split" / "train_log.json").read_text())
    assert [e["epoch"] for e in log] == [1, 2, 3]
    other = tiny_config("dct")
    other.ff_dim = 64
    with pytest.raises(ValueError, match="trained with seed=0, this run asks 1"):
        train_policy(
            train_config(
                collection, tmp_path / "split", policy="dct", epochs=4, num_envs=2, seed=1
            ),
            tiny_config("dct"),
        )
    with pytest.raises(ValueError, match="trained with num_envs=2, this run asks 3"):
        train_policy(
            train_config(collection, tmp_path / "split", policy="dct", epochs=4, num_envs=3),
            tiny_config("dct"),
        )
    with pytest.raises(ValueError, match="episodes of PressButton, not of task='PickPlace'"):
        train_policy(
            train_config(collection, tmp_path / "x", task="PickPlace", epochs=1), tiny_config("dct")
        )
    with pytest.raises(ValueError, match="last.pt: trained with another dct policy config"):
        train_policy(
            train_config(collection, tmp_path / "split", policy="dct", epochs=4, num_envs=2), other
        )


def test_feature_dropout_zeroes_whole_rollouts_reproducibly(collection, tmp_path):
    """Each rollout's cached features are kept or zeroed whole, at about the recipe's rate, the
    same for the same (seed, epoch, environment); the demonstrations' features stay."""
    ones = {"features": torch.ones(400, 6, 8), "mask": torch.ones(400, 6)}
    batch = {"epoch": 3, "env_index": 1, "demos": dict(ones), "rollouts": dict(ones)}
    cfg = train_config(collection, tmp_path, policy="scan", feature_dropout=0.5, shift=0)
    dropped = prepare(batch, cfg, torch.device("cpu"))
    kept = dropped["rollouts"]["features"].flatten(1)
    assert ((kept == 0).all(1) | (kept == 1).all(1)).all()
    assert 0.4 < kept[:, 0].mean() < 0.6
    assert torch.equal(dropped["demos"]["features"], ones["features"])
    again = prepare(batch, cfg, torch.device("cpu"))["rollouts"]["features"]
    assert torch.equal(again, dropped["rollouts"]["features"])
    other = prepare({**batch, "epoch": 4}, cfg, torch.device("cpu"))["rollouts"]["features"]
    assert not torch.equal(other, dropped["rollouts"]["features"])
    off = dataclasses.replace(cfg, feature_dropout=0.0)
    assert torch.equal(
        prepare(batch, off, torch.device("cpu"))["rollouts"]["features"], ones["features"]
    )
    with pytest.raises(ValueError, match="feature_dropout=1.0: must be in"):
        dataclasses.replace(cfg, feature_dropout=1.0)
    with pytest.raises(ValueError, match="needs a policy with frozen_encoder=True"):
        train_policy(cfg, tiny_config("scan"))  # end to end: nothing cached to drop
    # a checkpoint written before the field existed trained without it: not resumed under it
    then = {"train_config": {"task": "PressButton"}, "data_key": "k"}
    check_same_training(tmp_path / "last.pt", then, {"feature_dropout": 0.0}, "k")
    with pytest.raises(ValueError, match="trained with feature_dropout=0.0, this run asks 0.5"):
        check_same_training(tmp_path / "last.pt", then, {"feature_dropout": 0.5}, "k")


def test_paper_profile_runs_one_iteration(collection, tmp_path):
    cfg = TrainPolicyConfig.from_preset(
        "PressButton",
        "scan",
        "paper",
        data=collection,
        out=tmp_path / "paper",
        epochs=1,
        num_envs=1,
        max_frames=4,
        progress=False,
    )
    assert cfg.shift == 0
    config = POLICIES.preset("scan", "paper")
    assert config.visual.arch == "resnet18"
    final = train_policy(cfg, config)
    assert load_policy(final, name="scan").config.visual.arch == "resnet18"


def test_train_config_defaults_and_errors():
    mini = TrainPolicyConfig.from_preset(policy="scan")
    assert (
        mini.max_frames == 0
        and mini.num_envs == 0
        and mini.out == Path("runs/PressButton/policies/scan")
    )
    assert TrainPolicyConfig.from_preset(policy="naive_dc").max_frames == 8
    assert TrainPolicyConfig.from_preset(task="CloseDrawer", profile="paper").epochs == 160
    paper = TrainPolicyConfig.from_preset(profile="paper")
    assert (paper.lr, paper.weight_decay, paper.shift, paper.max_frames) == (1e-4, 1e-2, 0, 0)
    assert (
        mini.rollout_frames,
        TrainPolicyConfig.from_preset(policy="naive_dc").rollout_frames,
        paper.rollout_frames,
    ) == ("even", "random", "even")
    assert POLICIES.preset("scan", "mini").proprio and not POLICIES.preset("scan", "paper").proprio
    assert TrainPolicyConfig.from_preset(composition=[3, 4]).composition == (3, 4)
    assert (mini.composition, mini.epochs, paper.composition) == ((5, 2), 100, (5, 10))
    assert (mini.feature_dropout, paper.feature_dropout) == (0.5, 0.0)
    assert TrainPolicyConfig.from_preset(policy="naive_dc").composition == (5, 8)
    assert (
        POLICIES.preset("dct", "mini").subgoal_weight > 0
        and POLICIES.preset("dct", "paper").subgoal_weight == 0
    )
    with pytest.raises(ValueError, match="composition"):
        TrainPolicyConfig.from_preset(composition=(3, 0))
    with pytest.raises(ValueError, match="demo_frames=1"):
        POLICIES.preset("dct", "mini", demo_frames=1)
    demo = TrainPolicyConfig.from_preset(policy="dct", profile="demo")
    assert (demo.epochs, demo.composition, demo.shift) == (20, (3, 2), 0)
    assert POLICIES.preset("dct", "mini").frozen_encoder
    assert not POLICIES.preset("dct", "paper").frozen_encoder
    assert TrainPolicyConfig.from_preset(policy="naive_dc", profile="demo").composition == (3, 4)
    assert POLICIES.preset("dct", "demo") == POLICIES.preset(
        "dct", "mini"
    )  # demo trains the mini models
    with pytest.raises(ValueError, match="profile='huge'"):
        TrainPolicyConfig.from_preset(profile="huge")
    with pytest.raises(ValueError, match="unknown policy 'bc'"):
        TrainPolicyConfig.from_preset(policy="bc")
    with pytest.raises(ValueError, match="max_frames=1"):
        TrainPolicyConfig.from_preset(max_frames=1)


def test_stage_subgoals_are_where_each_stage_ends():
    from aed_models.data import stage_subgoals

    tcp = np.arange(6, dtype=np.float32)[:, None] * np.ones(
        (1, 3), np.float32
    )  # frame t at t metres
    goals = stage_subgoals(tcp, np.array([0, 0, 1, 1, 2]))  # step 2 enters stage 1, step 4 stage 2
    assert goals[:, 0].tolist() == [3, 3, 3, 5, 5, 5]
    assert stage_subgoals(tcp[:1], np.array([], dtype=np.int16))[:, 0].tolist() == [0]
    with pytest.raises(ValueError, match="subgoal_weight"):
        POLICIES.preset("naive_dc", "mini", proprio=False, subgoal_weight=1.0)
    with pytest.raises(ValueError, match="localizer needs proprio"):
        POLICIES.preset("naive_dc", "mini", proprio=False, subgoal_weight=0.0)


def test_the_pointer_head_chooses_among_the_located_offsets():
    from aed_models.policies.base import PointerSubgoalHead

    head = PointerSubgoalHead(in_dim=10, num_targets=2)
    offsets = torch.tensor([[1.0, 2.0, 3.0, -4.0, -5.0, -6.0]])
    with torch.no_grad():
        head.select[-1].weight.zero_()
        head.select[-1].bias.copy_(torch.tensor([0.0, 50.0]))  # the second stage's point
    assert torch.allclose(head(torch.randn(1, 10), offsets), offsets[:, 3:])
    with torch.no_grad():
        head.select[-1].bias.zero_()  # undecided: halfway, whatever the input
    assert torch.allclose(head(torch.randn(1, 10), offsets), torch.tensor([[-1.5, -1.5, -1.5]]))
    assert POLICIES.preset("scan", "mini").subgoal_head == "pointer"
    with pytest.raises(ValueError, match="needs a localizer"):
        POLICIES.preset("scan", "mini", localizer=None)
    with pytest.raises(ValueError, match="linear or pointer"):
        POLICIES.preset("scan", "mini", subgoal_head="mlp")


def test_diagnostic_scripts_run_on_a_collection(collection):
    floor = load_script("action_floor")
    x, y = floor.privileged_inputs(collection)
    assert x.shape[1] == 9 and y.shape == (len(x), 3) and torch.isfinite(x).all()
    assert np.isfinite(
        floor.held_out_mse(x, (y - y.mean(0)) / y.std(0).clamp_min(1e-3), steps=3, seed=0)
    )


def test_policy_benchmark_trains_every_mini_policy():
    bench = load_script("bench_policies")
    for name in POLICIES:  # the mini profile's losses need proprio and stage targets in the batch
        policy = make_policy(name, POLICIES.preset(name, "mini"))
        assert (
            bench.training_rate(
                policy, bench.Config(train_frames=2, repeats=1), torch.device("cpu")
            )
            > 0
        )


def test_demonstrations_are_thinned_by_the_datas_rule():
    from aed_models.data import subsample
    from aed_models.policies.base import thin_sequences

    lengths = [3, 10, 17]
    mask = torch.arange(17)[None] < torch.tensor(lengths)[:, None]
    frames = torch.arange(17.0)[None, :, None].expand(3, 17, 2) * mask[..., None]
    thinned, new_mask, _ = thin_sequences(frames, mask, None, limit=5)
    for row, length in enumerate(lengths):
        kept = thinned[row, new_mask[row], 0].long().numpy()
        assert np.array_equal(kept, subsample(np.arange(length), 5))


@pytest.mark.parametrize("name", list(POLICIES))
def test_action_chunks_learn_later_actions_and_are_ensembled_online(name, batch):
    policy = tiny_policy(name, action_chunk=3)
    policy.set_action_stats(torch.randn(50, 4) * 0.2)
    with pytest.raises(ValueError, match=r"action_chunk=3 needs rollouts\['action_chunks'\]"):
        policy.loss(batch)  # the fixture's chunks are the preset's width
    rollouts = batch["rollouts"]
    later = torch.arange(12)[:, None] + torch.arange(3)[None]
    rollouts["chunk_valid"] = later[None] < (rollouts["lengths"] - 1)[:, None, None]
    rollouts["action_chunks"] = rollouts["actions"][:, later.clamp_max(11)]
    loss, parts = policy.loss(batch)
    loss.backward()
    assert torch.isfinite(loss) and parts["pos_mse"] > 0
    policy.eval()
    rollout, proprio = rollouts["frames"][:1], rollouts["proprio"][:1]
    with torch.no_grad():
        out = policy({"frames": rollout, "proprio": proprio}, batch["demos"])
    assert out["pos_chunk"].shape == (1, 12, 3, 3) and out["grip_chunk"].shape == (1, 12, 3, 1)
    assert torch.equal(out["pos"], out["pos_chunk"][..., 0, :])
    policy.reset(batch["demos"])
    for t in range(6):  # by hand: predicted at t - age, its element `age`, the oldest weighted most
        action = policy.act(rollout[0, t], proprio=proprio[0, t])
        ages = range(min(t, 2), -1, -1)
        w = torch.tensor([np.exp(-0.01 * i) for i in range(len(ages))])
        w = w / w.sum()
        pos = sum(wi * out["pos_chunk"][0, t - a, a] for wi, a in zip(w, ages, strict=True))
        grip = sum(wi * out["grip_chunk"][0, t - a, a] for wi, a in zip(w, ages, strict=True))
        np.testing.assert_allclose(action, policy.to_action(pos, grip).numpy(), atol=1e-5)

"""What the code produces, summarised: the resolved recipes, trained weights and episodes.

`tests/fixtures/fingerprint.json` was written by this module before the presets redesign (#21),
against the API of then; the module now reads the same facts through today's API, and
`tests/test_fingerprint.py` checks that they are what they were. Never regenerate it to make a
test pass: an intended change is listed, with its reason, in `test_fingerprint.INTENDED`.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aed_tasks import PAPER_TASK_ORDER

STORED = Path(__file__).with_name("fixtures") / "fingerprint.json"
TASKS = PAPER_TASK_ORDER
PROFILES = ("mini", "paper")
# The demo's profiles then -> the presets now: `aed demo --profile mini` ran the demo's counts
# with mini models, which is now the `demo` preset.
DEMO_PRESETS = {"mini": "demo", "paper": "paper"}
TRAIN_FIELDS = (
    "epochs",
    "num_envs",
    "max_frames",
    "rollout_frames",
    "shift",
    "lr",
    "weight_decay",
    "data",
    "out",
    "augment",
)


def plain(x: Any) -> Any:
    """JSON-comparable form: tuples as lists, paths as strings, dataclasses as dicts."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return plain(dataclasses.asdict(x))
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x


def train_fields(cfg: Any) -> dict[str, Any]:
    """A training config's resolved fields, with the episodes one iteration draws."""
    return {
        **{k: plain(getattr(cfg, k)) for k in TRAIN_FIELDS if hasattr(cfg, k)},
        "num_envs": cfg.num_envs or None,  # None (then) and 0 (now): every environment
        "draws": list(iteration_draws(cfg)),
    }


def iteration_draws(cfg: Any) -> tuple[int, int, int]:
    """(demonstrations, successes, failures) one training iteration draws from an environment."""
    from aed_models.data import COMPOSITIONS

    if hasattr(cfg, "policy") and not hasattr(cfg, "detector"):
        c = cfg.composition
        return (c[0], c[1], 0) if c else astuple(COMPOSITIONS["policy"])
    from aed_models.detectors import DETECTORS

    only_successes = DETECTORS.model_type(cfg.detector).trains_on == "successes"
    if cfg.composition is None:
        return astuple(COMPOSITIONS["svdd" if only_successes else "detector"])
    demos, successes, failures = cfg.composition
    return (demos, successes + failures, 0) if only_successes else (demos, successes, failures)


def astuple(composition: Any) -> tuple[int, int, int]:
    return (composition.num_demos, composition.num_successes, composition.num_failures)


# --- recipes: what every command resolves to ----------------------------------------------------
def policy_recipes() -> dict[str, Any]:
    from aed_models.policies import POLICIES
    from aed_models.train.policy import TrainPolicyConfig

    out = {}
    for profile in PROFILES:
        for name in POLICIES:
            out[f"model/{name}/{profile}"] = plain(POLICIES.preset(name, profile).to_dict())
            for task in TASKS:
                out[f"train/{name}/{profile}/{task}"] = train_fields(
                    TrainPolicyConfig.from_preset(task, name, profile)
                )
    return out


def detector_recipes() -> dict[str, Any]:
    from aed_models.detectors import DETECTORS, requires_policy
    from aed_models.train.detector import TrainDetectorConfig

    out = {}
    for profile in PROFILES:
        for name in DETECTORS:
            out[f"model/{name}/{profile}"] = plain(DETECTORS.preset(name, profile))
            policy = "dct" if requires_policy(name) else None
            for task in TASKS:
                cfg = TrainDetectorConfig.from_preset(task, name, profile, policy=policy)
                out[f"train/{name}/{profile}/{task}"] = train_fields(cfg)
    return out


def protocol_counts(checkpoint: Path) -> dict[str, Any]:
    import aed_tasks
    from aed_eval.collect import CollectConfig
    from aed_eval.rollout import RolloutConfig

    keys = (
        "num_envs",
        "num_demos",
        "num_successes",
        "num_failures",
        "num_episodes",
        "horizon",
        "out",
        "demos",
    )
    out = {}
    for profile in PROFILES:
        for task in TASKS:
            for split in ("base", "novel"):
                size = aed_tasks.get_task(task).catalogue_sizes[split]
                collect = CollectConfig.from_preset(task, split, profile)
                out[f"collect/{profile}/{task}/{split}"] = counts(collect, keys, size)
                rollout = RolloutConfig.from_preset(
                    task, split=split, profile=profile, checkpoint=checkpoint
                )
                out[f"rollout/{profile}/{task}/{split}"] = counts(rollout, keys, size)
    return out


def counts(cfg: Any, keys: tuple[str, ...], size: int) -> dict[str, Any]:
    """A config's counts; `num_envs` None for every environment of the split (then: None; now:
    the catalogue's size), or when explicit `envs` make it irrelevant."""
    found = {k: plain(getattr(cfg, k)) for k in keys if hasattr(cfg, k)}
    if "num_envs" in found and (found["num_envs"] == size or getattr(cfg, "envs", ())):
        found["num_envs"] = None
    return found


def demo_stages(profile: str) -> dict[str, Any]:
    """The collection, training and rollout configs `aed demo` builds (nothing is run)."""
    from aed_eval.demo import DemoConfig, plan_stages

    planned = plan_stages(DemoConfig.from_preset(task="PressButton", profile=DEMO_PRESETS[profile]))
    jobs = {stage.name: [cfg for _, cfg in stage.jobs] for stage in planned}
    seen = {
        "collect": jobs["collect base split"] + jobs["collect novel split"],
        "policy": jobs["train policies"],
        "detector": jobs["train detectors"],
    }
    keys = ("envs", "num_envs", "num_demos", "num_successes", "num_failures", "out", "shard_size")
    return {
        "collect": [counts(c, keys, size=-1) for c in seen["collect"]],
        "policy": [{"policy": c.policy, **train_fields(c)} for c in seen["policy"]],
        "detector": [
            {"detector": c.detector, "policy": c.policy, **train_fields(c)}
            for c in seen["detector"]
        ],
    }


# --- weights: tiny trainings on synthetic collections (no simulation) ---------------------------
def tensor_summary(state_dict: dict[str, torch.Tensor]) -> dict[str, list[float]]:
    """Per tensor: sum and sum of absolute values (float tensors only)."""
    return {
        k: [float(v.double().sum()), float(v.double().abs().sum())]
        for k, v in sorted(state_dict.items())
        if v.is_floating_point()
    }


def policy_collection(root: Path) -> Path:
    from aed_tasks import trajectory
    from tests.models.test_policies import synthetic

    info = {"env_id": "aed_tasks:AED-PressButton-base", "env_kwargs": {}, "max_episode_steps": 100}
    for env_index in range(3):
        for role, n in (("demo", 2), ("agent_success", 3)):
            writer = trajectory.ShardWriter(root / f"{role}_env{env_index:03d}_0000.h5")
            for k in range(n):
                writer.add(
                    *synthetic(
                        role,
                        env_index,
                        seed=100 * env_index + 10 * (role == "demo") + k,
                        steps=8 + 2 * k,
                    )
                )
            writer.commit(info, {"env_index": env_index, "group": role})
    return root


def detector_collection(root: Path) -> Path:
    from aed_tasks import trajectory
    from tests.test_data import synthetic

    info = {"env_id": "aed_tasks:AED-PickPlace-base", "env_kwargs": {}, "max_episode_steps": 250}
    for env_index in (0, 1):
        for role in ("demo", "agent_success", "agent_failure"):
            writer = trajectory.ShardWriter(root / f"{role}_env{env_index:03d}_0000.h5")
            for k in range(2):
                writer.add(*synthetic(role, env_index, seed=100 * env_index + k, steps=10 + 2 * k))
            writer.commit(info, {"env_index": env_index, "group": role})
    return root


def trained_policies(root: Path) -> dict[str, Any]:
    from aed_models.policies import load_policy
    from aed_models.train.policy import TrainPolicyConfig, train_policy
    from tests.models.test_policies import tiny_config

    data = policy_collection(root / "policy_data")
    out = {}
    for name in ("naive_dc", "dct", "scan"):
        cfg = TrainPolicyConfig.from_preset(  # end to end, shifted: the mini recipe of then
            "PressButton",
            name,
            data=data,
            out=root / name,
            epochs=2,
            progress=False,
            shift=4,
            feature_dropout=0.0,
        )
        config = tiny_config(name)
        config.action_chunk = 1  # the actor of then: one action a step
        out[name] = tensor_summary(load_policy(train_policy(cfg, config)).state_dict())
    return out


def trained_detectors(root: Path, policy_path: Path) -> dict[str, Any]:
    from aed_models.detectors import DETECTORS, load_detector, make_detector, requires_policy
    from aed_models.train.detector import TrainDetectorConfig, train_detector
    from tests.models.test_detectors import TINY

    data = detector_collection(root / "detector_data")
    out = {}
    for name in DETECTORS:
        needs_policy = requires_policy(name)
        sizes = {k: v for k, v in TINY[name].items() if k not in ("history_dim", "task_dim")}
        if name == "rnd_oe":
            sizes["max_steps"] = 16
        torch.manual_seed(0)
        config = make_detector(name, **TINY[name]).config if not needs_policy else None
        if needs_policy:
            config = DETECTORS.preset(name, "mini", **sizes)
        cfg = TrainDetectorConfig.from_preset(
            "PickPlace",
            name,
            policy=str(policy_path) if needs_policy else None,
            data=data,
            out=root / name,
            epochs=1,
            progress=False,
            precision="fp32",  # the recipe of then: mini's visual baselines now train in bf16
        )
        out[name] = tensor_summary(load_detector(train_detector(cfg, config)).state_dict())
    return out


def tiny_policy_file(root: Path) -> Path:
    from aed_models.nn import VisualHeadConfig
    from aed_models.policies import POLICIES, make_policy, save_policy

    torch.manual_seed(0)
    config = POLICIES.preset(
        "naive_dc",
        "mini",
        visual=VisualHeadConfig(arch="small_cnn", out_dim=16, width=4),
        localizer=None,
        subgoal_head="linear",  # the pointer head needs a localizer
        action_chunk=1,  # the actor of then
    )
    path = root / "tiny_policy" / "policy.pt"
    path.parent.mkdir(parents=True)
    save_policy(
        path,
        make_policy("naive_dc", config).eval(),
        extra={"train_split": "base", "train_envs": [0]},
    )
    return path


# --- episodes: an expert collection and a policy rollout (simulated) ----------------------------
def episode_summary(root: Path) -> list[dict[str, Any]]:
    """Per episode: role, lengths, action sums, outcome and labels (no rendered pixels)."""
    from aed_tasks import trajectory

    rows = []
    for ref in sorted(
        trajectory.scan_collection(root).episodes(), key=lambda r: (r.path.name, r.traj)
    ):
        import h5py

        with h5py.File(ref.path, "r") as h5:
            group = h5[ref.traj]
            actions = group["actions"][()].astype(np.float64)
            labels = group["error_label"][()] if "error_label" in group else np.zeros(0)
        rows.append(
            {
                "shard": ref.path.name,
                "traj": ref.traj,
                "role": ref.role,
                "steps": int(len(actions)),
                "action_sum": [round(float(x), 4) for x in actions.sum(0)],
                "success": bool(ref.success),
                "labels": int(np.asarray(labels).sum()),
            }
        )
    return rows


def episodes(root: Path, policy_path: Path) -> dict[str, Any]:
    from aed_eval.collect import CollectConfig, run_collection
    from aed_eval.rollout import RolloutConfig, run_rollouts

    state = root / "state"
    run_collection(
        CollectConfig.from_preset(
            task="PickPlace",
            split="base",
            envs=(0,),
            num_demos=1,
            num_successes=1,
            num_failures=1,
            num_explore=0,  # the experts' episodes, as when the fingerprint was stored
            shard_size=1,
            obs_mode="state",
            out=state,
            progress=False,
        )
    )
    demos = root / "novel"
    run_collection(
        CollectConfig.from_preset(
            task="PressButton", split="novel", envs=(0,), num_demos=1, out=demos, progress=False
        )
    )
    rollouts = root / "rollouts"
    run_rollouts(
        RolloutConfig.from_preset(
            task="PressButton",
            policy="naive_dc",
            checkpoint=policy_path,
            split="novel",
            demos=demos,
            out=rollouts,
            envs=(0,),
            num_episodes=2,
            num_demos=1,
            horizon=6,
            progress=False,
        )
    )
    return {
        "collect": episode_summary(state),
        "demos": episode_summary(demos),
        "rollouts": episode_summary(rollouts),
    }


def fingerprint() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        policy_path = tiny_policy_file(root)
        return {
            "recipes": {**policy_recipes(), **detector_recipes()},
            "protocol": protocol_counts(policy_path),
            "demo": {profile: demo_stages(profile) for profile in PROFILES},
            "policies": trained_policies(root),
            "detectors": trained_detectors(root, policy_path),
            "episodes": episodes(root, policy_path),
        }


if __name__ == "__main__":
    from aed_eval.logs import quiet_maniskill

    quiet_maniskill()
    result = fingerprint()
    if "--write" in sys.argv:
        STORED.parent.mkdir(exist_ok=True)
        STORED.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
        print(f"wrote {STORED}")
    else:
        print(json.dumps(result, indent=1, sort_keys=True)[:4000])

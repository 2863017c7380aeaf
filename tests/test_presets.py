"""A profile names one recipe everywhere: `aed demo`, `aed train-*` and the library agree, and
every command's `--help` shows the preset's numbers."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from aed_eval import cli, train
from aed_eval.demo import DemoConfig, plan_stages
from aed_eval.presets import PROTOCOLS
from aed_models.detectors import DETECTORS, requires_policy
from aed_models.policies import POLICIES
from aed_models.recipe import PROFILES, DetectorRecipe, PolicyRecipe
from aed_models.train.detector import TrainDetectorConfig
from aed_models.train.policy import TrainPolicyConfig
from tests.helpers import aed

TASK = "PressButton"


def demo_training_configs(profile: str) -> tuple[list, list]:
    """The policy and detector training configs `aed demo --profile <profile>` plans."""
    jobs = {
        s.name: [cfg for _, cfg in s.jobs]
        for s in plan_stages(DemoConfig.from_preset(TASK, profile))
    }
    return jobs["train policies"], jobs["train detectors"]


def parsed(command: str, *args: str):
    """The config `aed <command> <args>` would run with (parsed, not run)."""
    return cli.parse_preset_command(command, list(args))


@pytest.mark.parametrize("profile", PROFILES)
def test_the_demo_trains_the_named_preset(profile):
    policies, detectors = demo_training_configs(profile)
    assert [c.policy for c in policies] == list(PROTOCOLS[profile].policies)
    for cfg in policies:
        command = parsed(
            "train-policy", "--task", TASK, "--policy", cfg.policy, "--profile", profile
        )
        assert cfg.recipe() == command.recipe() == POLICIES.recipe(cfg.policy, profile, TASK)
        assert cfg.num_envs == command.num_envs == DemoConfig.from_preset(TASK, profile).train_envs
    assert sorted({c.detector for c in detectors}) == sorted(
        DemoConfig.from_preset(TASK, profile).detectors
    )
    for cfg in detectors:
        args = ("--task", TASK, "--detector", cfg.detector, "--profile", profile)
        command = parsed("train-detector", *args, *(("--policy", cfg.policy) if cfg.policy else ()))
        assert cfg.recipe() == command.recipe() == DETECTORS.recipe(cfg.detector, profile, TASK)
        assert cfg.policy == command.policy and cfg.out == Path(
            "runs/demo"
        ) / command.out.relative_to("runs")


@pytest.mark.parametrize("profile", PROFILES)
def test_library_and_command_line_resolve_the_same_recipe(profile):
    for name in POLICIES:
        library = TrainPolicyConfig.from_preset(TASK, name, profile)
        assert (
            library.recipe()
            == parsed("train-policy", "--policy", name, "--profile", profile).recipe()
        )
        assert isinstance(library.recipe(), PolicyRecipe)
    for name in DETECTORS:
        policy = "dct" if requires_policy(name) else None
        library = TrainDetectorConfig.from_preset(TASK, name, profile, policy=policy)
        args = ["--detector", name, "--profile", profile, *(["--policy", "dct"] if policy else [])]
        assert library.recipe() == parsed("train-detector", *args).recipe()
        assert isinstance(library.recipe(), DetectorRecipe)


def test_flags_override_the_preset_and_the_preset_follows_its_choosers():
    cfg = parsed(
        "train-policy",
        "--profile",
        "paper",
        "--task",
        "CloseDrawer",
        "--epochs",
        "3",
        "--lr",
        "0.01",
    )
    assert (cfg.epochs, cfg.lr, cfg.weight_decay, cfg.shift) == (3, 0.01, 1e-2, 0)
    assert cfg.num_envs == train.training_envs("CloseDrawer", "paper")
    rollout = parsed("rollout", "--task", "PickPlace", "--policy", "dct", "--split", "base")
    assert rollout.out == Path("runs/PickPlace/rollouts/dct/base") and rollout.horizon == 250
    collect = parsed("collect", "--task", "PickPlace", "--split", "novel", "--profile", "paper")
    assert (collect.num_demos, collect.num_successes, collect.num_failures, collect.num_envs) == (
        5,
        0,
        0,
        42,
    )
    explore = [
        parsed(
            "collect", "--task", "PressButton", "--split", split, "--profile", profile
        ).num_explore
        for split, profile in (("base", "mini"), ("novel", "mini"), ("base", "paper"))
    ]
    assert explore == [12, 0, 0]  # the mini scene encoder's frames; the paper has no encoder
    demo = parsed("demo", "--profile", "demo", "--rollouts", "2")
    assert dataclasses.replace(DemoConfig.from_preset(), rollouts=2) == demo


@pytest.mark.parametrize(
    "command", ["train-policy", "train-detector", "train-localizer", "collect", "rollout", "demo"]
)
def test_help_shows_the_presets_numbers(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main([command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    flat = " ".join(text.replace("│", " ").split())
    optional = ("--ray-address", "--suboptimal-demos")  # unset means: no cluster, same as --demos
    assert flat.count("(default: None)") == sum(flat.count(f"{o} ") for o in optional), flat
    sized = {
        "train-policy": ("--epochs INT", "(default: 100)", "(default: 5 8)"),
        "train-detector": (
            "--epochs INT",
            "(default: 5 10 10)",
        ),
        "train-localizer": ("--updates INT", "(default: 250)", "(default: 32)"),
        "collect": ("--num-demos INT", "(default: 5)", "(default: 10)"),
        "rollout": ("--num-episodes INT", "(default: 5)", "(default: 200)"),
        "demo": ("--rollouts INT", "(default: 4)"),
    }[command]
    for piece in sized:
        assert piece in flat, (piece, flat)


def test_bad_profile_or_model_is_one_line_and_exit_2(caplog, capsys):
    for args, named in (
        (["train-policy", "--profile", "huge"], "huge"),
        (["train-detector", "--detector", "nope"], "nope"),
        (["rollout", "--policy", "bc"], "unknown policy 'bc'"),
        (["collect", "--task", "Juggle"], "Juggle"),
    ):
        status, errors, _ = aed(args, caplog, capsys)
        assert status == 2 and len(errors) == 1 and named in errors[0], (args, errors)
        assert "\n" not in errors[0]


@pytest.mark.parametrize(
    ("task", "base", "train_envs", "novel"),
    [("CloseDrawer", 18, 14, 18), ("PressButton", 27, 23, 18), ("FactoryPacking", 27, 23, 12)],
)
def test_mini_counts_fit_every_catalogue(task, base, train_envs, novel):
    """Mini trains on at most 23 base environments and rolls out in at most 18 novel ones; a
    smaller catalogue gives all it has, the 4 calibration environments always held out."""
    assert parsed("collect", "--task", task, "--split", "base").num_envs == base
    assert parsed("collect", "--task", task, "--split", "novel").num_envs == novel
    assert parsed("train-policy", "--task", task, "--policy", "scan").num_envs == train_envs
    assert parsed("rollout", "--task", task, "--policy", "scan").num_envs == novel
    demo = DemoConfig.from_preset(task, "mini")
    assert demo.calibration_env_indices == tuple(range(train_envs, base))


def test_mini_trains_the_visual_baselines_under_bf16_autocast_and_the_rest_in_float32():
    """bf16 where the from-scratch CNNs cost the time (their losses follow float32's);
    SVDDED's distances and the feature-based detectors stay float32; `paper` is float32."""
    mini = {name: DETECTORS.recipe(name, "mini", TASK).precision for name in DETECTORS}
    assert mini == {
        "svdd_ed": "fp32",
        "taskemb_ed": "bf16",
        "lstm_ed": "bf16",
        "dct_ed": "bf16",
        "probe": "fp32",
        "rnd_oe": "fp32",
    }
    assert {DETECTORS.recipe(name, "paper", TASK).precision for name in DETECTORS} == {"fp32"}
    recipe = dataclasses.asdict(DETECTORS.recipe("lstm_ed", "mini", TASK))
    with pytest.raises(ValueError, match=r"precision='fp16': known \['fp32', 'bf16'\]"):
        DetectorRecipe(**{**recipe, "precision": "fp16"})

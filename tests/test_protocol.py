"""The protocol measures detection, not length: equal-length rollouts through the real rollout
code, references at chance on them, calibration on the policy's own held-out successes, and
no model scored on an environment it trained on."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch

import aed_tasks
from aed_eval import metrics
from aed_eval.calibrate import CalibrateConfig, calibrate_detectors
from aed_eval.collect import CollectConfig, episode_seed, run_collection
from aed_eval.evaluate import ending_views, labelled_metrics
from aed_eval.rollout import (
    ROLE,
    RolloutConfig,
    RolloutRunner,
    paper_ending,
    plan_shards,
    stored_rollouts,
)
from aed_models.detectors import make_detector, save_detector
from aed_models.layout import RunLayout
from aed_models.nn import VisualHeadConfig
from aed_models.policies import POLICIES, make_policy, save_policy
from aed_tasks import solve
from aed_tasks.locks import FolderLockedError, folder_lock
from tests.helpers import aed

TASK = "PressButton"
HORIZON = 110  # the clean expert presses within ~60 steps and rests by ~105


class ScriptedPolicy:
    """Rollout k replays the clean expert's actions of that rollout's seed (it succeeds early),
    or holds still (it fails): drives the real rollout code with known outcomes."""

    def __init__(self, plans: list[np.ndarray | None]):
        self.plans, self.k, self.t = plans, -1, 0

    def reset(self, demos) -> None:
        self.k, self.t = self.k + 1, 0

    def act(self, obs) -> np.ndarray:
        plan = self.plans[self.k]
        self.t += 1
        if plan is None or self.t > len(plan):
            return np.zeros(4, dtype=np.float32)
        return plan[self.t - 1]


def expert_actions(split: str, env_index: int, k: int, seed: int = 0) -> np.ndarray:
    env = gym.make(aed_tasks.env_id(TASK, split), obs_mode="state")
    episode = solve(
        env, seed=episode_seed(seed, TASK, split, env_index, ROLE, k, 0), env_index=env_index
    )
    env.close()
    assert episode.succeeded
    return episode.actions


def roll_out(cfg: RolloutConfig, plans: list[np.ndarray | None]) -> None:
    runner = RolloutRunner(cfg, policy=ScriptedPolicy(plans))
    try:
        for shard in plan_shards(cfg, list(cfg.envs)):
            runner.run(shard)
    finally:
        runner.close()


def save_trained(path: Path, model, train_envs: list[int], **extra) -> None:
    """A tiny checkpoint that records, as training writes it, where it trained."""
    provenance = {
        "train_config": {},
        "train_split": "base",
        "train_envs": train_envs,
        "task": TASK,
        **extra,
    }
    (save_policy if hasattr(model, "act") else save_detector)(path, model, extra=provenance)


@pytest.fixture(scope="module")
def setting(tmp_path_factory) -> dict:
    """runs/ with a tiny policy and LSTMED trained on base environment 0, demonstrations of novel
    environment 0 and base environments 0 and 1."""
    runs = tmp_path_factory.mktemp("runs")
    layout = RunLayout(runs)
    torch.manual_seed(0)
    policy = make_policy(
        "naive_dc",
        POLICIES.preset(
            "naive_dc",
            "mini",
            visual=VisualHeadConfig(arch="small_cnn", out_dim=16, width=4),
            localizer=None,
            subgoal_head="linear",  # the pointer head needs a localizer
        ),
    )
    layout.policy(TASK, "naive_dc").parent.mkdir(parents=True)
    save_trained(layout.policy(TASK, "naive_dc"), policy.eval(), [0])
    detector = layout.detector(TASK, "lstm_ed", "naive_dc")
    detector.parent.mkdir(parents=True)
    save_trained(
        detector,
        make_detector("lstm_ed", arch="small_cnn", feature_dim=16, width=4, hidden_dim=16).eval(),
        [0],
    )
    for split, envs in (("novel", (0,)), ("base", (0, 1))):
        run_collection(
            CollectConfig.from_preset(
                task=TASK,
                split=split,
                envs=envs,
                num_demos=1,
                num_successes=0,
                num_failures=0,
                num_explore=0,
                out=layout.data(TASK, split),
                progress=False,
            )
        )
    return {"runs": runs, "layout": layout}


def rollout_config(
    setting: dict, split: str, envs: tuple[int, ...], out: Path, **kwargs
) -> RolloutConfig:
    return RolloutConfig.from_preset(
        task=TASK,
        policy="naive_dc",
        runs=setting["runs"],
        split=split,
        envs=envs,
        out=out,
        num_demos=1,
        progress=False,
        **kwargs,
    )


@pytest.fixture(scope="module")
def endings(setting) -> dict[str, list[dict]]:
    """Novel environment 0: rollout 0 succeeds early, rollout 1 fails; under each ending."""
    plans = [expert_actions("novel", 0, 0), None]
    stored = {}
    for ending in ("horizon", "success"):
        out = setting["runs"] / f"endings-{ending}"
        roll_out(
            rollout_config(
                setting,
                "novel",
                (0,),
                out,
                num_episodes=2,
                shard_size=2,
                horizon=HORIZON,
                ending=ending,
            ),
            plans,
        )
        stored[ending] = stored_rollouts(out, "naive_dc").entries
    return stored


@pytest.mark.slow
def test_rollout_length_carries_no_outcome_by_default(endings):
    success, failure = endings["horizon"]
    assert success["success"] and not failure["success"]
    assert success["elapsed_steps"] == failure["elapsed_steps"] == HORIZON
    assert success["success_step"] < HORIZON - 20 and failure["success_step"] is None
    frames = [e["elapsed_steps"] + 1 for e in endings["horizon"]]
    failed = np.array([False, True])
    time_only = metrics.rollout_maxima(metrics.time_only_scores(frames, HORIZON))
    assert metrics.rollout_curves(time_only, failed, metrics.thresholds("probability")).auroc == 0.5


@pytest.mark.slow
def test_the_papers_ending_stops_at_success_and_is_a_view_of_the_default(endings):
    success, failure = endings["success"]
    assert success["success"] and not failure["success"]
    assert (
        success["elapsed_steps"]
        == success["success_step"] + 1
        < failure["elapsed_steps"]
        == HORIZON
    )
    assert paper_ending(endings["horizon"][0]) == (
        success["elapsed_steps"],
        True,
    )  # the view equals the option
    assert paper_ending(endings["horizon"][1]) == (HORIZON, False)
    view = ending_views(endings["horizon"], "horizon")["success"]
    assert view.frames == [e["elapsed_steps"] + 1 for e in endings["success"]]
    time_only = metrics.rollout_maxima(metrics.time_only_scores(view.frames, HORIZON))
    assert (
        metrics.rollout_curves(time_only, view.failed, metrics.thresholds("probability")).auroc
        == 1.0
    )  # length leaks


def test_references_sit_at_chance_on_equal_length_rollouts():
    frames, failed = [121] * 60, np.arange(60) < 30
    for scores in (metrics.time_only_scores(frames, 120), metrics.random_scores(frames, seed=3)):
        maxima = metrics.rollout_maxima(scores)
        grid = metrics.thresholds("probability")
        auroc = metrics.rollout_curves(maxima, failed, grid).auroc
        low, high = metrics.curve_intervals(maxima, failed, grid, num=300)["auroc"]
        assert low <= 0.5 <= high and low <= auroc <= high


def test_the_labelled_table_matches_frames_in_time_where_the_step_count_scores_chance():
    """Errors come late in a labelled episode: the step count alone ranks their frames high,
    and only the time-matched AUROC puts it at chance."""
    rng = np.random.default_rng(0)
    refs = []
    for k in range(20):
        onset = int(rng.integers(40, 80)) if k % 2 else None
        labels = np.zeros(120, dtype=bool) if onset is None else np.arange(120) >= onset
        refs.append(
            SimpleNamespace(
                frame_labels=lambda labels=labels: labels, error_onset=onset, onset_frame=onset
            )
        )
    cfg = SimpleNamespace(bootstrap=200, seed=0, window=10)
    time_only = labelled_metrics(metrics.time_only_scores([120] * 20, 120), refs, {}, cfg)
    assert time_only["frame_auroc"] > 0.75
    assert abs(time_only["time_matched_auroc"] - 0.5) < 0.05  # within a bin, onsets still lean
    oracle = [r.frame_labels().astype(float) for r in refs]  # sees the error itself
    assert labelled_metrics(oracle, refs, {}, cfg)["time_matched_auroc"] == 1.0


@pytest.fixture(scope="module")
def base_rollouts(setting) -> Path:
    """Base environment 0 (the models trained there) and held-out 1: a success and a failure
    each."""
    out = setting["layout"].rollouts(TASK, "naive_dc", "base")
    for env in (0, 1):
        roll_out(
            rollout_config(
                setting, "base", (env,), out, num_episodes=2, shard_size=2, horizon=HORIZON
            ),
            [expert_actions("base", env, 0), None],
        )
    return out


@pytest.mark.slow
def test_calibration_uses_the_policys_successes_in_held_out_environments(setting, base_rollouts):
    (body,) = calibrate_detectors(
        CalibrateConfig(
            task=TASK,
            policy="naive_dc",
            detectors=("lstm_ed",),
            alphas=(0.5, 0.1),
            num_demos=1,
            runs=setting["runs"],
            progress=False,
        )
    ).values()
    assert (
        body["envs"] == [1]
        and body["num_rollouts"] == 1
        and body["of_rollouts"] == 2
        and body["source"] == "policy"
    )
    assert (
        np.isfinite(body["thresholds"]["0.5"]) and body["thresholds"]["0.1"] is None
    )  # 1 success cannot promise 10%
    assert not body["diagnostic"]


def test_calibration_refuses_a_detector_folder_another_run_writes(setting):
    folder = setting["layout"].detector(TASK, "lstm_ed", "naive_dc").parent
    before = sorted(p.name for p in folder.iterdir())
    with folder_lock(folder):  # e.g. the detector being trained again
        with pytest.raises(FolderLockedError, match="another run"):
            calibrate_detectors(
                CalibrateConfig(
                    task=TASK, policy="naive_dc", detectors=("lstm_ed",), runs=setting["runs"]
                )
            )
        assert sorted(p.name for p in folder.iterdir()) == sorted([*before, ".aed.lock"])


@pytest.mark.slow
@pytest.mark.parametrize("command", ["evaluate", "calibrate"])
def test_scoring_a_model_on_its_training_environments_is_refused(
    setting, base_rollouts, command, caplog, capsys
):
    args = [command, "--task", TASK, "--policy", "naive_dc", "--detectors", "lstm_ed"]
    args += ["--num-demos", "1", "--runs", str(setting["runs"]), "--no-progress"]
    args += (
        ["--split", "base", "--out", str(setting["runs"] / "eval-base")]
        if command == "evaluate"
        else ["--envs", "0", "1"]
    )
    status, errors, _ = aed(args, caplog, capsys)
    assert status == 2 and len(errors) == 1, errors
    assert "policy naive_dc trained on base environments [0]" in errors[0]
    assert "--allow-trained-envs" in errors[0] and "\n" not in errors[0]
    status, errors, out = aed([*args, "--allow-trained-envs"], caplog, capsys)
    assert status == 0 and not errors and "DIAGNOSTIC" in out, errors
    if command == "evaluate":
        results = json.loads((setting["runs"] / "eval-base" / "results.json").read_text())
        assert results["diagnostic"] and results["trained_env_overlap"]["policy naive_dc"] == [0]


@pytest.mark.parametrize("task", sorted(aed_tasks.TASKS))
def test_every_horizon_follows_the_measured_expert_lengths(task):
    """Twice the longest measured clean expert episode, at most the time limit
    (results/expert_lengths)."""
    cls = aed_tasks.get_task(task)
    measured = json.loads(
        (
            Path(__file__).resolve().parents[1] / "results" / "expert_lengths" / f"{task}.json"
        ).read_text()
    )
    longest = measured["results"][0]["max_length"]
    assert cls.eval_horizon == min(cls.max_episode_steps, -(-2 * longest // 10) * 10)
    assert longest < cls.eval_horizon <= cls.max_episode_steps

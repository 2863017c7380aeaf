"""Online monitoring: a policy and an error detector beside a live env (a Gymnasium wrapper).

`AEDMonitor` asks the policy for each frame's action, scores the frame with the detector
(post-processed as offline scoring is, `aed_models.detectors.postprocess`) and puts the score,
the alarm and the latency in `info`. `step(None)` plays the policy's action, any other action
is played instead (the detector keeps watching). On an alarm it stops the episode or hands over
to a correction routine (the paper's pilot: a safe pose above the table), then to the policy.
Scores of frame t depend only on frames <= t, so they equal the offline scores.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

import gymnasium as gym
import numpy as np
import torch
import tyro

from aed_models.detectors.postprocess import OnlinePostprocess

OnAlarm = Literal["stop", "correct", "none"]
SAFE_TCP = np.array([0.0, 0.0, 0.30])  # above the table centre (table top: z = 0)
MAX_DELTA = 0.1  # metres per unit action of pd_ee_delta_pos

logger = logging.getLogger(__name__)


def move_to_safe_pose(
    env: gym.Env, gripper: float, max_steps: int = 40, tol: float = 0.01
) -> list[Any]:
    """The pilot's correction: bring the TCP above the table centre, the gripper held as it is."""
    base = env.unwrapped
    frames = []
    for _ in range(max_steps):
        tcp = base.agent.tcp.pose.p[0].detach().cpu().numpy()
        error = SAFE_TCP - tcp
        if np.linalg.norm(error) < tol:
            break
        action = np.concatenate([np.clip(error / MAX_DELTA, -1, 1), [gripper]]).astype(np.float32)
        frames.append(env.step(action))
    return frames


class AEDMonitor(gym.Wrapper):
    """Runs `policy` on `env` under the watch of `detector` (see the module docstring).

    Args:
        env: an AED env with rgbd observations (one env, CPU).
        policy: a trained `DCPolicy`.
        detector: a trained `ErrorDetector` (policy-dependent ones read the policy's features).
        demos: the environment's demonstrations, padded (`frames`, `mask`).
        threshold: alarm when a frame's score reaches it.
        on_alarm: stop, correct, or none (only report).
        correction: the correction routine (default: `move_to_safe_pose`).
        max_corrections: corrections per episode; later alarms are only reported.
    """

    def __init__(
        self,
        env: gym.Env,
        policy: Any,
        detector: Any,
        demos: dict[str, Any],
        threshold: float,
        on_alarm: OnAlarm = "stop",
        correction: Callable[[gym.Env, float], list[Any]] | None = None,
        max_corrections: int = 1,
    ):
        super().__init__(env)
        if on_alarm not in ("stop", "correct", "none"):
            raise ValueError(f"on_alarm={on_alarm!r}: stop, correct or none")
        self.policy, self.detector, self.demos = policy.eval(), detector.eval(), demos
        self.threshold, self.on_alarm = float(threshold), on_alarm
        self.correction = correction or move_to_safe_pose
        self.max_corrections = max_corrections
        self.postprocess = OnlinePostprocess(detector)
        self.scores: list[float] = []

    def _watch(self, obs: Any) -> dict[str, Any]:
        """Policy action for `obs` and the detector's score of its frame."""
        start = time.perf_counter()
        action = self.policy.act(obs)
        policy_latency = time.perf_counter() - start
        start = time.perf_counter()
        features = self.policy.features() if self.detector.requires_policy else None
        frame = None if self.detector.requires_policy else self.policy.observation_frame(obs)
        with torch.inference_mode():
            score = self.postprocess(float(self.detector.step(frame, features)))
        latency = time.perf_counter() - start
        self.next_action = action
        self.scores.append(score)
        alarm = score >= self.threshold
        return {
            "aed_score": score,
            "aed_alarm": alarm,
            "aed_latency_s": latency,
            "aed_policy_latency_s": policy_latency,
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.policy.reset(self.demos)
        self.detector.reset(self.demos)
        self.postprocess.reset()
        self.scores, self.corrections, self.alarms = [], 0, 0
        info.update(self._watch(obs))
        return obs, info

    def step(self, action: Any = None):
        action = self.next_action if action is None else action
        start = time.perf_counter()
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["aed_env_step_s"] = time.perf_counter() - start
        info.update(self._watch(obs))
        if info["aed_alarm"]:
            self.alarms += 1
            if self.on_alarm == "stop":
                truncated = True
            elif self.on_alarm == "correct" and self.corrections < self.max_corrections:
                self.corrections += 1
                alarm_score = info["aed_score"]
                corrected = self.correction(self.env, float(np.asarray(action).reshape(-1)[-1]))
                if corrected:  # control goes back to the policy from the frame after the correction
                    obs, reward, terminated, truncated, info = corrected[-1]
                    info.update(self._watch(obs))
                info.update(aed_corrected=True, aed_alarm=True, aed_alarm_score=alarm_score)
        info["aed_corrections"] = self.corrections
        return obs, reward, terminated, truncated, info


# --- command -------------------------------------------------------------------------------------
def monitor(
    task: str = "PressButton",
    policy: str = "naive_dc",
    detector: str = "probe",
    env_index: int = 0,
    split: Literal["base", "novel"] = "novel",
    seed: int = 0,
    threshold: float | None = None,
    alpha: float = 0.1,
    on_alarm: OnAlarm = "stop",
    num_demos: int = 5,
    runs: Path = Path("runs"),
    out: Annotated[
        Path | None,
        tyro.conf.arg(
            help="video path (default runs/<task>/<policy>/monitor/<detector>_env<k>.mp4)"
        ),
    ] = None,
) -> int:
    """Run a policy with a detector beside it in one environment and write a video with the score
    curve.

    The alarm threshold: `threshold`, else the detector's calibration on the policy for
    `alpha` (`aed calibrate`), else 0.9."""
    import aed_tasks
    from aed_eval.calibrate import load_policy_checked, read_calibration, threshold_at
    from aed_eval.scoring import Demonstrations, load_checked_detector
    from aed_models.layout import RunLayout

    task = aed_tasks.get_task(task).task_name
    if num_demos < 1 or not 0.0 < alpha < 1.0:
        raise ValueError(f"num_demos={num_demos}, alpha={alpha}: num_demos >= 1, alpha in (0, 1)")
    layout = RunLayout(runs)
    policy_model, sha = load_policy_checked(layout.policy(task, policy))
    path = layout.detector(task, detector, policy)
    loaded = load_checked_detector(path, detector, task, sha)
    if threshold is None:
        calibration = read_calibration(path, loaded.model.checkpoint_sha256)
        threshold = threshold_at(calibration, alpha) if calibration is not None else None
        if threshold is None:
            logger.warning(
                "%s: no calibrated threshold for alpha %s; alarms at 0.9", path.parent, alpha
            )
            threshold = 0.9
    demos = Demonstrations(layout.data(task, split), split, num_demos)
    if env_index not in demos:
        raise ValueError(
            f"env_index={env_index}: no {split} demonstrations in runs/{task}/data/{split}"
        )
    env = AEDMonitor(
        gym.make(aed_tasks.env_id(task, split), env_index=env_index),
        policy_model,
        loaded.model,
        demos[env_index],
        threshold,
        on_alarm,
    )
    obs, info = env.reset(seed=seed)
    frames, latencies, policy_latencies, env_steps, done = (
        [_rgb(obs)],
        [info["aed_latency_s"]],
        [],
        [],
        False,
    )
    while not done:
        obs, _, terminated, truncated, info = env.step(None)
        frames.append(_rgb(obs))
        latencies.append(info["aed_latency_s"])
        policy_latencies.append(info["aed_policy_latency_s"])
        env_steps.append(info["aed_env_step_s"])
        done = bool(np.asarray(terminated).any() or np.asarray(truncated).any())
    env.close()
    out = Path(out or Path(runs) / task / policy / "monitor" / f"{detector}_env{env_index:03d}.mp4")
    write_video(out, frames, env.scores, threshold)
    success = bool(np.asarray(info["success"]).any())
    print(
        f"{out}: {len(frames)} frames, success={success}, alarms={env.alarms}, "
        f"threshold {threshold:.3g}, detector step median {1e3 * np.median(latencies):.2f} ms, "
        f"policy act {1e3 * np.median(policy_latencies):.2f} ms, "
        f"env step {1e3 * np.median(env_steps):.1f} ms (detector overhead "
        f"{100 * np.median(latencies) / np.median(env_steps):.1f}% of the env step)"
    )
    return 0


def _rgb(obs: Any) -> np.ndarray:
    rgb = obs["sensor_data"]["front"]["rgb"]
    return (rgb.cpu().numpy() if hasattr(rgb, "cpu") else np.asarray(rgb))[0]


def write_video(
    path: Path,
    frames: list[np.ndarray],
    scores: list[float],
    threshold: float,
    scale: int = 3,
    fps: int = 20,
) -> None:
    """Camera frames with the score curve (and the threshold) drawn under them, as MP4."""
    import cv2

    height, width = frames[0].shape[:2]
    w, h, plot_h = width * scale, height * scale, 80 * scale // 2
    top = max(max(scores), threshold, 1e-6) * 1.05
    points = [
        (int(i * (w - 1) / max(len(scores) - 1, 1)), int(plot_h - 1 - s / top * (plot_h - 1)))
        for i, s in enumerate(scores)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h + plot_h))
    try:
        for t, frame in enumerate(frames):
            canvas = np.full((h + plot_h, w, 3), 255, dtype=np.uint8)
            canvas[:h] = cv2.resize(frame, (w, h), interpolation=cv2.INTER_NEAREST)
            plot = canvas[h:]
            y = int(plot_h - 1 - threshold / top * (plot_h - 1))
            cv2.line(plot, (0, y), (w - 1, y), (60, 60, 220), 1)
            if t > 0:
                cv2.polylines(
                    plot, [np.asarray(points[: t + 1], dtype=np.int32)], False, (40, 40, 40), 2
                )
            writer.write(cv2.cvtColor(canvas, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()

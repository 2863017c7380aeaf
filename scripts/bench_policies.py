"""Policy speed: online per-step latency at t = 10 and t = 200, and training frames/s.

Online: `reset` with 5 demonstrations of 100 frames, then `act` for 210 steps on 120 x 160
frames, `repeats` times; the latency at t is the median over the steps t-5 .. t+5 of each
step's median over the repeats (a step: visual head, task-embedding network, actor). With
per-frame caching (SCAN's LSTM state, DCT's key/value caches) t200 / t10 stays near 1.

Training: loss + backward + RMSprop step on one iteration (5 demos + 10 rollouts of
`train_frames` frames); frames/s counts every frame of the iteration, as the training loop
does; the median over `repeats` iterations (after one warm-up).

    python scripts/bench_policies.py
    python scripts/bench_policies.py --heads small_cnn --device cuda
"""

from __future__ import annotations

import json
import logging
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from aed_models.policies import POLICIES, make_policy

logger = logging.getLogger("bench_policies")
H, W = 120, 160
PROFILE = {"small_cnn": "mini", "resnet18": "paper"}  # the profile whose head this is


@dataclass
class Config:
    policies: tuple[str, ...] = tuple(POLICIES)
    heads: tuple[str, ...] = ("small_cnn", "resnet18")
    steps: int = 210
    """Online steps per rollout (>= 206: t = 200 is measured over steps 195..205)."""
    demo_frames: int = 100
    train_frames: int = 16
    """Frames per sequence in a training iteration (the CPU cannot afford the paper's ~100)."""
    repeats: int = 3
    device: str = "cpu"
    threads: int | None = None
    """torch CPU threads (default: torch's choice)."""
    out: Path | None = None
    """Also write the rows as JSON here."""


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def online_latency(policy, cfg: Config, device: torch.device) -> dict[int, float]:
    """Median step time (ms) at t = 10 and 200: per step the median over `repeats` rollouts
    (after a warm-up one), then the median over the steps t-5 .. t+5."""
    half = cfg.demo_frames // 2  # two stage targets: one stage done halfway, then the rest
    subgoal = torch.ones(5, cfg.demo_frames, 3, device=device)
    subgoal[:, half:, :2] = 0.5
    demos = {
        "frames": torch.rand(5, cfg.demo_frames, 4, H, W, device=device),
        "mask": torch.ones(5, cfg.demo_frames, dtype=torch.bool, device=device),
        "proprio": torch.rand(5, cfg.demo_frames, 5, device=device),
        "subgoal": subgoal,
    }
    frames = torch.rand(cfg.steps, 4, H, W, device=device)
    proprio = torch.rand(cfg.steps, 5, device=device)
    runs = []
    for r in range(cfg.repeats + 1):
        policy.reset(demos)
        times = []
        for t in range(cfg.steps if r else 20):
            sync(device)
            start = time.perf_counter()
            policy.act(frames[t], proprio=proprio[t])
            sync(device)
            times.append(time.perf_counter() - start)
        if r:
            runs.append(times)
    per_step = [statistics.median(step) for step in zip(*runs, strict=True)]
    return {t: statistics.median(per_step[t - 5 : t + 6]) * 1e3 for t in (10, 200)}


def training_rate(policy, cfg: Config, device: torch.device) -> float:
    optimizer = torch.optim.RMSprop(policy.parameters(), lr=1e-4, weight_decay=1e-2)
    n = cfg.train_frames
    batch = {
        "demos": {
            "frames": torch.rand(5, n, 4, H, W, device=device),
            "mask": torch.ones(5, n, dtype=torch.bool, device=device),
            "proprio": torch.rand(5, n, 5, device=device),
        },
        "rollouts": {
            "frames": torch.rand(10, n, 4, H, W, device=device),
            "mask": torch.ones(10, n, dtype=torch.bool, device=device),
            "actions": torch.rand(10, n, 4, device=device) * 2 - 1,
            "proprio": torch.rand(10, n, 5, device=device),
            "subgoal": torch.rand(10, n, 3, device=device),
        },
    }
    chunk = policy.config.action_chunk
    batch["rollouts"]["action_chunks"] = torch.rand(10, n, chunk, 4, device=device) * 2 - 1
    batch["rollouts"]["chunk_valid"] = torch.ones(10, n, chunk, dtype=torch.bool, device=device)
    if policy.localizer is not None:  # training reads the located points it cached
        width = 3 * policy.localizer.config.num_targets
        batch["rollouts"]["located"] = torch.rand(10, n, width, device=device)
    policy.train()
    rates = []
    for i in range(cfg.repeats + 1):
        sync(device)
        start = time.perf_counter()
        loss, _ = policy.loss(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        sync(device)
        if i:  # the first is a warm-up
            rates.append(15 * n / (time.perf_counter() - start))
    return statistics.median(rates)


def main(cfg: Config) -> list[dict]:
    device = torch.device(cfg.device)
    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    if cfg.steps < 206:
        raise ValueError(f"steps={cfg.steps}: must be >= 206 to measure t = 200")
    rows = []
    for head in cfg.heads:
        for name in cfg.policies:
            torch.manual_seed(0)
            config = POLICIES.preset(name, PROFILE[head])
            policy = make_policy(name, config).to(device)
            policy.set_action_stats(torch.rand(100, 4, device=device) * 2 - 1)
            latency = online_latency(policy, cfg, device)
            rate = training_rate(policy, cfg, device)
            rows.append(
                {
                    "policy": name,
                    "head": head,
                    "profile": PROFILE[head],
                    "params": policy.num_parameters(),
                    "step_ms_t10": round(latency[10], 2),
                    "step_ms_t200": round(latency[200], 2),
                    "ratio_t200_t10": round(latency[200] / latency[10], 2),
                    "train_frames_per_s": round(rate, 1),
                }
            )
            logger.info("%s", rows[-1])
    header = "| policy | head | params | step ms t=10 | step ms t=200 | t200/t10 | train frames/s |"
    where = (
        torch.cuda.get_device_name(device)
        if device.type == "cuda"
        else f"{platform.machine()}, {torch.get_num_threads()} threads"
    )
    lines = [
        f"device: {cfg.device} ({where}), train_frames {cfg.train_frames}",
        header,
        "|" + "---|" * 7,
    ]
    for r in rows:
        lines.append(
            f"| {r['policy']} | {r['head']} | {r['params'] / 1e6:.2f}M | {r['step_ms_t10']} | "
            f"{r['step_ms_t200']} | {r['ratio_t200_t10']} | {r['train_frames_per_s']} |"
        )
    print("\n".join(lines))
    if cfg.out is not None:
        cfg.out.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    import tyro

    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    main(tyro.cli(Config))

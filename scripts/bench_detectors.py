"""Benchmark the error detectors: online per-step latency, offline scoring and training
throughput.

Online: after `reset(demos)`, the median cost of one `step` around t = 10 and around t = 200
(DCTED's cached self-attention grows with t; LSTM-based detectors must not). Visual
detectors include their own frame encoder; PrObe and RND-OE get the policy's (f_h, f_zeta)
as inputs, so their numbers exclude the policy's own cost. Offline: the median cost of
`score` on one rollout of `horizon` frames given 5 demonstrations of `demo_frames` frames, the
demonstrations read at every call and prepared once for their environment (`prepare`), as
`aed evaluate` scores the rollouts of an environment one by one. Training: frames per second of
`loss` + backward + RMSprop step on one iteration of the detector composition (5 demos +
20 rollouts) at 4 x 120 x 160. Synthetic tensors: no data or policy needed.

    python scripts/bench_detectors.py                       # mini profile, every detector
    python scripts/bench_detectors.py --profile paper --detectors probe dct_ed
    python scripts/bench_detectors.py --profile paper --device cuda --train-iterations 10
"""

from __future__ import annotations

import json
import logging
import platform
import statistics
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import tyro

from aed_eval.logs import setup_logging
from aed_models.detectors import DETECTORS, PAPER_PARAMETERS, make_detector
from aed_models.detectors.base import to_device

logger = logging.getLogger("bench_detectors")
H, W = 120, 160


@dataclass
class Config:
    detectors: tuple[str, ...] = ()
    """Detectors to measure (default: all)."""
    profile: str = "mini"
    history_dim: int = 256
    """Policy feature sizes fed to PrObe / RND-OE (the paper's policies: 256)."""
    task_dim: int = 256
    horizon: int = 210
    """Online steps per rollout (latency is read around t=10 and t=200)."""
    demo_frames: int = 80
    """Frames per demonstration in offline scoring (the experts' episodes: 60-200)."""
    score_repeats: int = 5
    rollout_frames: int = 32
    """Frames per rollout in the training iteration."""
    train_iterations: int = 3
    threads: int = 1
    """torch threads (1: the cost of one detector on one core, as when monitoring online)."""
    device: str = "cpu"
    """torch device (cuda: the paper profile's sizes where they are meant to train)."""
    out: Path = Path("runs/bench")


@dataclass
class Row:
    detector: str
    parameters: int
    paper_parameters: float | None
    step_ms_t10: float
    step_ms_t200: float
    score_ms_demos_each_call: float
    score_ms_prepared: float
    train_frames_per_s: float


def synthetic_batch(
    b: int, t: int, n: int = 5, length: int = 32
) -> tuple[dict, tuple[torch.Tensor, torch.Tensor]]:
    g = torch.Generator().manual_seed(0)
    labels = torch.zeros(b, t)
    labels[b // 2 :, t // 2 :] = 1.0
    rollouts = {
        "frames": torch.rand(b, t, 4, H, W, generator=g),
        "mask": torch.ones(b, t, dtype=torch.bool),
        "lengths": torch.full((b,), t),
        "labels": labels,
        "is_failure": torch.arange(b) >= b // 2,
    }
    demos = {
        "frames": torch.rand(n, length, 4, H, W, generator=g),
        "mask": torch.ones(n, length, dtype=torch.bool),
    }
    return {"demos": demos, "rollouts": rollouts}, (
        torch.randn(b, t, Config.history_dim),
        torch.randn(b, t, Config.task_dim),
    )


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def online_latency(detector, demos: dict, cfg: Config) -> tuple[float, float]:
    """Median ms of one step around t=10 and t=200 (each step returns a float: it waits for the
    device)."""
    device = torch.device(cfg.device)
    detector.eval()
    frame = torch.rand(4, H, W, device=device)
    feats = (torch.randn(cfg.history_dim, device=device), torch.randn(cfg.task_dim, device=device))
    detector.reset(to_device(demos, device))
    times = []
    for _ in range(cfg.horizon):
        start = time.perf_counter()
        detector.step(frame, feats)
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times[5:16]), 1e3 * statistics.median(times[195:206])


def offline_scoring(detector, cfg: Config) -> tuple[float, float]:
    """Median ms of `score` on one rollout: the demonstrations read at every call, and prepared
    once (the two measured alternately, so that both see the same machine)."""
    device = torch.device(cfg.device)
    detector.eval()
    batch, features = to_device(synthetic_batch(1, cfg.horizon, length=cfg.demo_frames), device)
    features = features if detector.requires_policy else None
    raw, prepared = [], []
    with torch.inference_mode():
        ready = detector.prepare(batch["demos"])
        for _ in range(cfg.score_repeats):
            for demos, times in ((batch["demos"], raw), (ready, prepared)):
                start = time.perf_counter()
                detector.score(batch["rollouts"], demos, features)
                synchronize(device)
                times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(raw), 1e3 * statistics.median(prepared)


def train_throughput(detector, cfg: Config) -> float:
    device = torch.device(cfg.device)
    detector.train()
    b = 20
    batch, features = to_device(synthetic_batch(b, cfg.rollout_frames), device)
    if detector.trains_on == "successes":
        batch["rollouts"]["is_failure"][:] = False
    optimizer = torch.optim.RMSprop(
        [p for p in detector.parameters() if p.requires_grad], lr=1e-4, weight_decay=1e-2
    )
    rates = []
    for _ in range(cfg.train_iterations + 1):
        start = time.perf_counter()
        loss, _ = detector.loss(batch, features if detector.requires_policy else None)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        synchronize(device)
        rates.append(b * cfg.rollout_frames / (time.perf_counter() - start))
    return statistics.median(rates[1:])  # the first iteration warms up


def main(cfg: Config) -> None:
    setup_logging()
    torch.set_num_threads(cfg.threads)
    Config.history_dim, Config.task_dim = cfg.history_dim, cfg.task_dim
    names = cfg.detectors or tuple(DETECTORS)
    batch, _ = synthetic_batch(1, 1)
    rows = []
    for name in names:
        torch.manual_seed(0)
        overrides = {}
        if DETECTORS.model_type(name).requires_policy:
            overrides = {
                "history_dim": cfg.history_dim,
                **({"task_dim": cfg.task_dim} if name == "probe" else {}),
            }
        detector = make_detector(name, DETECTORS.preset(name, cfg.profile), **overrides).to(
            cfg.device
        )
        t10, t200 = online_latency(detector, batch["demos"], cfg)
        raw, prepared = offline_scoring(detector, cfg)
        rate = train_throughput(detector, cfg)
        rows.append(
            Row(
                name,
                detector.num_parameters(),
                PAPER_PARAMETERS.get(name),
                round(t10, 3),
                round(t200, 3),
                round(raw, 1),
                round(prepared, 1),
                round(rate, 1),
            )
        )
        logger.info("%s: %s", name, rows[-1])
    machine = (
        torch.cuda.get_device_name(cfg.device)
        if cfg.device.startswith("cuda")
        else platform.processor() or platform.machine()
    )
    meta = {
        "profile": cfg.profile,
        "threads": cfg.threads,
        "torch": torch.__version__,
        "machine": machine,
        "device": cfg.device,
    }
    cfg.out.mkdir(parents=True, exist_ok=True)
    (cfg.out / f"bench_detectors_{cfg.profile}.json").write_text(
        json.dumps({"meta": meta, "rows": [asdict(r) for r in rows]}, indent=2)
    )
    lines = [
        (
            f"profile {cfg.profile}, {cfg.threads} torch thread(s), "
            f"torch {torch.__version__}, {machine}"
        ),
        "",
        (
            f"| detector | parameters | paper | step ms (t=10) | step ms (t=200) | score ms, "
            f"{cfg.horizon} frames (demos read each call) | (prepared once) | train frames/s |"
        ),
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        paper = f"{r.paper_parameters / 1e6:.2f}M" if r.paper_parameters else "-"
        lines.append(
            f"| {r.detector} | {r.parameters / 1e6:.2f}M | {paper} | {r.step_ms_t10:.3f} | "
            f"{r.step_ms_t200:.3f} | {r.score_ms_demos_each_call:.0f} | "
            f"{r.score_ms_prepared:.0f} | {r.train_frames_per_s:.0f} |"
        )
    table = "\n".join(lines)
    (cfg.out / f"bench_detectors_{cfg.profile}.md").write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main(tyro.cli(Config))

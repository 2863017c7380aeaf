"""Can the demonstrations tell a policy where the button is, in scenes it never saw?

A diagnostic for issue #20: the scene encoder learns where base environments' buttons are,
not the novel split's (unseen colours and shapes). The novel environment's demonstrations,
though, show its button: the arm presses it at the demonstration's lowest TCP, and the first
frame shows it unoccluded at that place. This probe trains a fully convolutional feature map
to *match*: the feature under the pressed point of one episode's first frame (the query)
scores every cell of another frame of the same environment, and a softmax over the cells
should peak on the button, wherever it now stands. Trained on base environments, measured on
the novel split's demonstrations (each one's first frame, or every n-th, located from the
other ones' queries), as the horizontal error in cm beside the training mean's guess and,
given `--encoder`, the scene encoder's on the same frames.

    python scripts/demo_localizer.py --data runs/PressButton/data/base \
        --novel runs/PressButton/data/novel --encoder runs/PressButton/encoder/encoder.pt \
        --checkpoint runs/PressButton/localizer/map.pt [--every 4]
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch
import torch.nn.functional as F
import tyro
from torch import nn

from aed_models.data import DEPTH_SCALE_MM, EpisodeReader, load_episodes
from aed_models.encoder import load_encoder
from aed_tasks import trajectory

logger = logging.getLogger("demo_localizer")
CAMERA = "front"
STRIDE = 8  # the feature map's cell, in pixels


@dataclass
class Config:
    data: Path = Path("runs/PressButton/data/base")
    """Base collection to train on (demonstrations, successes, exploration episodes)."""
    novel: Path = Path("runs/PressButton/data/novel")
    """Novel collection whose demonstrations are located."""
    envs: int = 0
    """Train on the first N base environments (0: all)."""
    target: str = "button"
    """The articulation or actor located."""
    encoder: Path | None = None
    """Also score this scene encoder on the same frames."""
    steps: int = 2000
    """Adam updates."""
    batch: int = 32
    """Query / target pairs per update."""
    frames_per_episode: int = 6
    """Frames read per episode (its first, then random ones) for training targets."""
    colour: float = 0.3
    """Colour jitter strength, one draw for a query and its target (0: off)."""
    seed: int = 0
    every: int = 1000
    """Locate every n-th frame of each novel demonstration (the default: its first alone,
    where the arm has not moved)."""
    checkpoint: Path | None = None
    """Save the trained map here; if it exists already, load it instead of training."""
    out: Path | None = None
    """Write the results as JSON here."""


def colour_jitter(
    frames: torch.Tensor, strength: float, generator: torch.Generator
) -> torch.Tensor:
    """Recolour each sequence (B, L, 4, H, W) once: its RGB channels in a random order, each
    scaled by a gain in [1 - `strength`, 1 + `strength`], one sequence in five grey; depth
    as it is. A query and its target, one sequence, share the draw: the same object keeps
    one look, which need not be a colour the training split shows."""
    if strength == 0:
        return frames
    b = frames.shape[0]
    order = torch.stack([torch.randperm(3, generator=generator) for _ in range(b)])
    gains = 1.0 + strength * (2.0 * torch.rand(b, 3, generator=generator) - 1.0)
    grey = torch.rand(b, generator=generator) < 0.2
    rows = torch.arange(b)[:, None]
    rgb = frames[:, :, :3].transpose(1, 2)[rows, order].transpose(1, 2)
    rgb = rgb * gains.view(b, 1, 3, 1, 1)
    rgb = torch.where(grey.view(b, 1, 1, 1, 1), rgb.mean(dim=2, keepdim=True).expand_as(rgb), rgb)
    return torch.cat([rgb.clamp(0.0, 1.0), frames[:, :, 3:]], dim=2)


class MatchingMap(nn.Module):
    """(N, 4, H, W) -> (N, D, H / 8, W / 8) unit feature vectors, one per cell."""

    def __init__(self, width: int = 32, dim: int = 32):
        super().__init__()
        layers, channels = [], 4
        for w, stride in ((width, 2), (width, 2), (2 * width, 1), (2 * width, 2)):
            layers += [nn.Conv2d(channels, w, 3, stride, 1), nn.GroupNorm(8, w), nn.ReLU()]
            channels = w
        layers += [nn.Conv2d(channels, 2 * width, 3, 1, 2, dilation=2), nn.ReLU()]
        self.body = nn.Sequential(*layers, nn.Conv2d(2 * width, dim, 1))
        self.log_scale = nn.Parameter(torch.tensor(2.3))  # logits = cos similarity x ~10

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.body(frames), dim=1)

    def logits(self, maps: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """maps (N, D, h, w), queries (N, D) -> (N, h * w)."""
        return torch.einsum("ndhw,nd->nhw", maps, queries).flatten(1) * self.log_scale.exp()


def sample(maps: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear feature (N, D) of each map at its pixel (N, 2) = (u, v)."""
    h, w = maps.shape[-2:]
    cells = (pixels + 0.5) / STRIDE - 0.5
    grid = torch.stack([2 * cells[:, 0] / (w - 1) - 1, 2 * cells[:, 1] / (h - 1) - 1], dim=-1)
    out = F.grid_sample(maps, grid[:, None, None], align_corners=True)[:, :, 0, 0]
    return F.normalize(out, dim=1)


def project(points: np.ndarray, intrinsic: np.ndarray, extrinsic: np.ndarray) -> np.ndarray:
    """World points (N, 3) -> pixels (N, 2) of an OpenCV camera."""
    cam = points @ extrinsic[:, :3].T + extrinsic[:, 3]
    uvw = cam @ intrinsic.T
    return uvw[:, :2] / uvw[:, 2:]


def unproject(pixels: np.ndarray, depth_m: np.ndarray, intrinsic, extrinsic) -> np.ndarray:
    """Pixels (N, 2) at depths (N,) in metres -> world points (N, 3)."""
    rays = np.concatenate([pixels, np.ones((len(pixels), 1))], axis=1) @ np.linalg.inv(intrinsic).T
    cam = rays * depth_m[:, None]
    return (cam - extrinsic[:, 3]) @ extrinsic[:, :3]


@dataclass
class EpisodeInfo:
    ref: trajectory.EpisodeRef
    target: np.ndarray  # (3,) world position of the located object (it does not move here)
    pressed: np.ndarray | None  # (3,) the TCP at its lowest: where an expert touched it
    intrinsic: np.ndarray
    extrinsic: np.ndarray


def episode_info(ref: trajectory.EpisodeRef, target: str) -> EpisodeInfo:
    with h5py.File(ref.path, "r") as h5:
        group = h5[ref.traj]
        states = group["env_states"]
        kind = "articulations" if target in states["articulations"] else "actors"
        position = states[kind][target][0, :3]
        tcp = group["obs/extra/tcp_pose"][()][:, :3]
        params = group[f"obs/sensor_param/{CAMERA}"]
        intrinsic, extrinsic = params["intrinsic_cv"][0], params["extrinsic_cv"][0]
    pressed = tcp[tcp[:, 2].argmin()] if ref.role != "explore" else None
    return EpisodeInfo(ref, position.astype(np.float64), pressed, intrinsic, extrinsic)


class PairData:
    """Per base environment: query frames (first frames of expert episodes, with the pixel
    where the expert pressed) and target frames (any frame, with the pixel of the object's
    top: its position raised to the height where the environment's experts pressed it)."""

    def __init__(self, infos: list[EpisodeInfo], cfg: Config):
        rng = np.random.default_rng(cfg.seed)
        reader = EpisodeReader(CAMERA)
        heights: dict[int, list[float]] = {}
        for info in infos:
            if info.pressed is not None:
                heights.setdefault(info.ref.env_index, []).append(float(info.pressed[2]))
        self.queries: dict[int, list[tuple[torch.Tensor, np.ndarray]]] = {}
        self.targets: dict[int, list[tuple[torch.Tensor, np.ndarray]]] = {}
        for info in infos:
            ref = info.ref
            if ref.env_index not in heights:
                continue
            n = min(cfg.frames_per_episode, ref.num_frames)
            indices = np.concatenate([[0], rng.choice(np.arange(1, ref.num_frames), n - 1, False)])
            frames = reader.read(ref, indices).frames.half()
            top = info.target.copy()
            top[2] = np.median(heights[ref.env_index])
            pixel = project(top[None], info.intrinsic, info.extrinsic)[0]
            self.targets.setdefault(ref.env_index, []).extend((f, pixel) for f in frames)
            if info.pressed is not None:
                press = project(info.pressed[None], info.intrinsic, info.extrinsic)[0]
                self.queries.setdefault(ref.env_index, []).append((frames[0], press))
        self.envs = sorted(self.queries)

    def batch(self, size: int, rng: np.random.Generator):
        q_frames, q_pix, t_frames, t_pix = [], [], [], []
        for env in rng.choice(self.envs, size):
            q_f, q_p = self.queries[env][rng.integers(len(self.queries[env]))]
            t_f, t_p = self.targets[env][rng.integers(len(self.targets[env]))]
            q_frames.append(q_f), q_pix.append(q_p), t_frames.append(t_f), t_pix.append(t_p)
        pairs = torch.stack([torch.stack(q_frames), torch.stack(t_frames)], dim=1).float()
        return pairs, torch.tensor(np.array(q_pix)).float(), torch.tensor(np.array(t_pix)).float()


def target_cells(pixels: torch.Tensor, h: int, w: int) -> torch.Tensor:
    col = (pixels[:, 0] / STRIDE).floor().clamp(0, w - 1)
    row = (pixels[:, 1] / STRIDE).floor().clamp(0, h - 1)
    return (row * w + col).long()


def train(model: MatchingMap, data: PairData, cfg: Config) -> list[float]:
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    rng = np.random.default_rng([cfg.seed, 1])
    generator = torch.Generator().manual_seed(cfg.seed)
    losses = []
    for step in range(cfg.steps):
        pairs, q_pix, t_pix = data.batch(cfg.batch, rng)
        pairs = colour_jitter(pairs, cfg.colour, generator)
        maps = model(pairs.flatten(0, 1)).unflatten(0, (len(pairs), 2))
        queries = sample(maps[:, 0], q_pix)
        logits = model.logits(maps[:, 1], queries)
        loss = F.cross_entropy(logits, target_cells(t_pix, *maps.shape[-2:]))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        if (step + 1) % 250 == 0:
            logger.info("step %d: loss %.3f", step + 1, np.mean(losses[-250:]))
    return losses


def refined_pixel(logits: torch.Tensor) -> np.ndarray:
    """The best cell of a (h, w) score map, refined to the softmax-weighted mean of the cell
    centres around it (3 x 3): a pixel (u, v) finer than the map's 8-pixel cells."""
    h, w = logits.shape
    row, col = divmod(int(logits.argmax()), w)
    rows = slice(max(row - 1, 0), min(row + 2, h))
    cols = slice(max(col - 1, 0), min(col + 2, w))
    weights = torch.softmax(logits[rows, cols].flatten(), 0).view(logits[rows, cols].shape)
    ys = torch.arange(h, dtype=torch.float32)[rows]
    xs = torch.arange(w, dtype=torch.float32)[cols]
    v = float((weights.sum(1) * ys).sum() + 0.5) * STRIDE
    u = float((weights.sum(0) * xs).sum() + 0.5) * STRIDE
    return np.array([u, v])


@torch.no_grad()
def locate(
    model: MatchingMap, demos: list[EpisodeInfo], every: int, encoder=None, target: str = ""
) -> dict[str, list[np.ndarray]]:
    """Every `every`-th frame of each demonstration, located from the environment's other
    demonstrations (their mean query: the mean of their logits): per demonstration, the
    horizontal errors (m) of the localizer and, given one, the encoder."""
    model.eval()
    reader = EpisodeReader(CAMERA)
    errors: dict[str, list[np.ndarray]] = {"localizer": [], "encoder": []}
    for env in sorted({d.ref.env_index for d in demos}):
        infos = [d for d in demos if d.ref.env_index == env]
        firsts = torch.stack([reader.read(i.ref, np.array([0])).frames[0] for i in infos])
        presses = np.array([project(i.pressed[None], i.intrinsic, i.extrinsic)[0] for i in infos])
        queries = sample(model(firsts), torch.from_numpy(presses).float())
        start = len(errors["localizer"])
        for j, info in enumerate(infos):
            frames = reader.read(info.ref, np.arange(0, info.ref.num_frames, every)).frames
            maps = model(frames)
            query = torch.cat([queries[:j], queries[j + 1 :]]).mean(0)
            logits = model.logits(maps, query.expand(len(frames), -1)).view(-1, *maps.shape[-2:])
            pixels = np.array([refined_pixel(scores) for scores in logits])
            v = np.clip(pixels[:, 1].astype(int), 0, frames.shape[-2] - 1)
            u = np.clip(pixels[:, 0].astype(int), 0, frames.shape[-1] - 1)
            depth_m = (
                frames[np.arange(len(frames)), 3, v, u].double().numpy() * DEPTH_SCALE_MM / 1e3
            )
            located = unproject(pixels, depth_m, info.intrinsic, info.extrinsic)
            errors["localizer"].append(np.linalg.norm(located[:, :2] - info.target[:2], axis=1))
            if encoder is not None:
                column = encoder.config.state_names.index(f"{target}.x")
                predicted = encoder.predict_state(frames)[:, column : column + 2].numpy()
                errors["encoder"].append(np.linalg.norm(predicted - info.target[:2], axis=1))
        logger.info(
            "novel env %d: localizer errors (cm), median %.1f",
            env,
            100 * np.median(np.concatenate(errors["localizer"][start:])),
        )
    return errors


def summary(per_demo: list[np.ndarray], seed: int, draws: int = 1000) -> dict[str, object]:
    """Mean, median and share within 3 cm of the errors (cm), with 95% bootstrap intervals
    over demonstrations (a demonstration's frames resampled together)."""

    def stats(arrays: list[np.ndarray]) -> np.ndarray:
        e = np.concatenate(arrays)
        return np.array([100 * e.mean(), 100 * np.median(e), (e < 0.03).mean()])

    rng = np.random.default_rng(seed)
    boot = np.array(
        [stats([per_demo[i] for i in rng.integers(len(per_demo), size=len(per_demo))])
         for _ in range(draws)]
    )  # fmt: skip
    low, high = np.percentile(boot, [2.5, 97.5], axis=0)
    point = stats(per_demo)
    return {
        **{name: float(v) for name, v in zip(("mean", "median", "within_3cm"), point, strict=True)},
        **{
            f"{name}_95": [float(lo), float(hi)]
            for name, lo, hi in zip(("mean", "median", "within_3cm"), low, high, strict=True)
        },
        "n": int(sum(len(e) for e in per_demo)),
        "demonstrations": len(per_demo),
    }


def main(cfg: Config) -> dict:
    torch.manual_seed(cfg.seed)
    start = time.perf_counter()
    episodes = load_episodes(cfg.data, split="base")
    if cfg.envs:
        keep = sorted({e.env_index for e in episodes})[: cfg.envs]
        episodes = [e for e in episodes if e.env_index in keep]
    infos = [episode_info(ref, cfg.target) for ref in episodes]
    model = MatchingMap()
    if cfg.checkpoint and cfg.checkpoint.is_file():
        saved = torch.load(cfg.checkpoint, weights_only=True)
        model.load_state_dict(saved["model"])
        losses, trained = saved["losses"], saved["config"]
    else:
        data = PairData(infos, cfg)
        logger.info(
            "%d environments, %d episodes read in %.0f s",
            len(data.envs),
            len(episodes),
            time.perf_counter() - start,
        )
        losses = train(model, data, cfg)
        trained = {k: str(v) for k, v in vars(cfg).items()}
        trained["train_seconds"] = str(round(time.perf_counter() - start, 1))
        if cfg.checkpoint:
            cfg.checkpoint.parent.mkdir(parents=True, exist_ok=True)
            torch.save(
                {"model": model.state_dict(), "losses": losses, "config": trained}, cfg.checkpoint
            )
    encoder = load_encoder(cfg.encoder) if cfg.encoder else None
    novel = [
        episode_info(ref, cfg.target)
        for ref in load_episodes(cfg.novel, split="novel")
        if ref.role == "demo"
    ]
    errors = locate(model, novel, cfg.every, encoder, cfg.target)
    train_xy = np.array([i.target[:2] for i in infos])
    novel_xy = np.array([i.target[:2] for i in novel])
    lengths = [len(range(0, i.ref.num_frames, cfg.every)) for i in novel]
    guesses = np.linalg.norm(novel_xy - train_xy.mean(0), axis=1)
    errors["mean_guess"] = [np.full(n, g) for n, g in zip(lengths, guesses, strict=True)]
    window = max(1, len(losses) // 10)
    result = {
        "trained_with": trained,
        "every": cfg.every,
        "loss_first_last_tenth": [
            float(np.mean(losses[:window])),
            float(np.mean(losses[-window:])),
        ],
        "novel_demo_xy_error_cm": {
            name: summary(per_demo, cfg.seed) for name, per_demo in errors.items() if per_demo
        },
    }
    print(json.dumps(result, indent=2))
    if cfg.out:
        cfg.out.parent.mkdir(parents=True, exist_ok=True)
        cfg.out.write_text(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    main(tyro.cli(Config))

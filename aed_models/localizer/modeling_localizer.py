"""The matching map and the localizer built on it: queries from demonstrations, points in frames."""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from aed_models.data import DEPTH_SCALE_MM
from aed_models.localizer.configuration_localizer import LocalizerConfig


class StageQueries(NamedTuple):
    """What the demonstrations tell the localizer of each of the K stage targets: the matching
    map's feature under it (K, D) and the height (m) at which they ended the stage (K,)."""

    features: torch.Tensor
    heights: torch.Tensor


class MatchingMap(nn.Module):
    """(N, 4, H, W) -> (N, dim, H / stride, W / stride) unit feature vectors, one per cell
    of `stride` x `stride` pixels (8 or 4: the last conv at stride 2 or 1)."""

    def __init__(self, width: int, dim: int, stride: int = 8):
        super().__init__()
        layers, channels = [], 4
        last = 2 if stride == 8 else 1
        for w, s in ((width, 2), (width, 2), (2 * width, 1), (2 * width, last)):
            layers += [nn.Conv2d(channels, w, 3, s, 1), nn.GroupNorm(8, w), nn.ReLU()]
            channels = w
        layers += [nn.Conv2d(channels, 2 * width, 3, 1, 2, dilation=2), nn.ReLU()]
        self.body = nn.Sequential(*layers, nn.Conv2d(2 * width, dim, 1))
        self.log_scale = nn.Parameter(torch.tensor(2.3))  # logits = cosine similarity x ~10

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.body(frames), dim=1)

    def logits(self, maps: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """maps (N, D, h, w) and one query each (N, D) -> (N, h * w)."""
        return torch.einsum("ndhw,nd->nhw", maps, queries).flatten(1) * self.log_scale.exp()


def sample(maps: torch.Tensor, pixels: torch.Tensor, stride: int) -> torch.Tensor:
    """The unit feature (N, D) of each map (N, D, h, w) of `stride`-pixel cells at its pixel
    (N, 2) = (u, v), bilinear."""
    h, w = maps.shape[-2:]
    cells = (pixels + 0.5) / stride - 0.5
    grid = torch.stack(
        [2 * cells[:, 0] / max(w - 1, 1) - 1, 2 * cells[:, 1] / max(h - 1, 1) - 1], dim=-1
    )
    out = F.grid_sample(maps, grid[:, None, None].to(maps.dtype), align_corners=True)
    return F.normalize(out[:, :, 0, 0], dim=1)


def target_cells(pixels: torch.Tensor, h: int, w: int, stride: int) -> torch.Tensor:
    """The flat index of the `stride`-pixel cell (N,) holding each pixel (N, 2)."""
    col = (pixels[:, 0] / stride).floor().clamp(0, w - 1)
    row = (pixels[:, 1] / stride).floor().clamp(0, h - 1)
    return (row * w + col).long()


def refined_pixels(logits: torch.Tensor, stride: int) -> torch.Tensor:
    """(..., h, w) score maps of `stride`-pixel cells -> (..., 2) pixels (u, v): the best
    cell, refined to the softmax-weighted mean of the cell centres in the 3 x 3 around it."""
    h, w = logits.shape[-2:]
    flat = logits.flatten(-2)
    best = flat.argmax(-1, keepdim=True)
    rows = torch.arange(h, device=logits.device).repeat_interleave(w)
    cols = torch.arange(w, device=logits.device).repeat(h)
    near = ((rows - rows[best]).abs() <= 1) & ((cols - cols[best]).abs() <= 1)
    weights = torch.softmax(flat.masked_fill(~near, float("-inf")), dim=-1)
    v = (weights * rows.to(weights.dtype)).sum(-1)
    u = (weights * cols.to(weights.dtype)).sum(-1)
    return (torch.stack([u, v], dim=-1) + 0.5) * stride


def nearest_surface(depth: torch.Tensor, window: int) -> torch.Tensor:
    """Depth maps (B, H, W) -> at each pixel the nearest depth within `window` pixels (a
    (2 window + 1)^2 square); zeros (no depth) are left out, and stay where all are zero."""
    if window == 0:
        return depth
    seen = torch.where(depth > 0, depth, torch.full_like(depth, float("inf")))
    near = -F.max_pool2d(-seen[:, None], 2 * window + 1, stride=1, padding=window)[:, 0]
    return torch.where(torch.isfinite(near), near, torch.zeros_like(near))


def colour_jitter(
    frames: torch.Tensor, strength: float, generator: torch.Generator
) -> torch.Tensor:
    """Recolour each sequence (B, L, 4, H, W) once: RGB channels in a random order, each scaled
    by a gain in [1 - strength, 1 + strength], one sequence in five grey; depth as it is. A
    query and its target share a sequence, so an object keeps one look, which need not be one
    the training split shows."""
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


class TargetLocalizer(nn.Module):
    """The matching map and the fixed camera it works through (OpenCV intrinsics and
    world-to-camera extrinsics, buffers set from the training data)."""

    def __init__(self, config: LocalizerConfig):
        super().__init__()
        self.config = config
        self.map = MatchingMap(config.width, config.dim, config.stride)
        self.register_buffer("intrinsic", torch.eye(3, dtype=torch.float64))
        self.register_buffer("extrinsic", torch.eye(3, 4, dtype=torch.float64))
        self.sha256 = ""

    def set_camera(self, intrinsic: torch.Tensor, extrinsic: torch.Tensor) -> None:
        self.intrinsic.copy_(torch.as_tensor(intrinsic, dtype=torch.float64).reshape(3, 3))
        self.extrinsic.copy_(torch.as_tensor(extrinsic, dtype=torch.float64).reshape(3, 4))

    def project(self, points: torch.Tensor) -> torch.Tensor:
        """World points (..., 3) -> pixels (..., 2)."""
        cam = points.double() @ self.extrinsic[:, :3].T + self.extrinsic[:, 3]
        uvw = cam @ self.intrinsic.T
        return (uvw[..., :2] / uvw[..., 2:]).float()

    def unproject(self, pixels: torch.Tensor, depth_m: torch.Tensor) -> torch.Tensor:
        """Pixels (..., 2) seen at depths (...) in metres -> world points (..., 3)."""
        ones = torch.ones_like(pixels[..., :1])
        rays = torch.cat([pixels, ones], dim=-1).double() @ torch.linalg.inv(self.intrinsic).T
        cam = rays * depth_m.double()[..., None]
        return ((cam - self.extrinsic[:, 3]) @ self.extrinsic[:, :3]).float()

    def at_height(self, pixels: torch.Tensor, heights: torch.Tensor) -> torch.Tensor:
        """Pixels (..., 2) -> the world points (..., 3) where their rays cross the horizontal
        planes z = heights (...)."""
        centre = self.unproject(pixels, torch.zeros_like(pixels[..., 0]))  # the camera
        direction = self.unproject(pixels, torch.ones_like(pixels[..., 0])) - centre
        along = (heights.to(centre.dtype) - centre[..., 2]) / direction[..., 2]
        return centre + along[..., None] * direction

    def queries(self, first_frames: torch.Tensor, points: torch.Tensor) -> StageQueries:
        """Demonstrations' first frames (N, 4, H, W) and where each ended its K stages
        (N, K, 3) -> per stage, the mean over demonstrations of the map's feature under its
        point and of its height."""
        n, k = points.shape[:2]
        if k != self.config.num_targets:
            raise ValueError(
                f"{k} stage points per demonstration, the localizer locates "
                f"{self.config.num_targets}"
            )
        maps = self.map(first_frames)
        pixels = self.project(points).reshape(n * k, 2)
        feats = sample(maps.repeat_interleave(k, dim=0), pixels, self.config.stride)
        return StageQueries(feats.view(n, k, -1).mean(0), points[..., 2].float().mean(0))

    def locate(self, frames: torch.Tensor, queries: StageQueries) -> torch.Tensor:
        """Frames (B, 4, H, W) and the demonstrations' queries -> world points (B, K, 3): per
        stage, the best-matching cell refined to a pixel, lifted at the frame's depth there;
        a point lifted further than `height_tolerance` from the stage's height is put at that
        height along the pixel's ray instead (a stage that ends in mid-air or behind what
        the camera sees: the depth there is of the surface behind)."""
        maps = self.map(frames)
        b, _, h, w = maps.shape
        features = queries.features.to(maps.dtype)
        logits = torch.einsum("bdhw,kd->bkhw", maps, features) * self.map.log_scale.exp()
        pixels = refined_pixels(logits, self.config.stride)  # (B, K, 2)
        height, width = frames.shape[-2:]
        u = pixels[..., 0].long().clamp(0, width - 1)
        v = pixels[..., 1].long().clamp(0, height - 1)
        rows = torch.arange(b, device=frames.device)[:, None]
        depth = nearest_surface(frames[:, 3], self.config.depth_window)
        depth_m = depth[rows, v, u] * DEPTH_SCALE_MM / 1000.0
        lifted = self.unproject(pixels, depth_m)
        if self.config.height_tolerance == 0:
            return lifted
        heights = queries.heights.to(lifted.device).expand(b, -1)
        off = (lifted[..., 2] - heights).abs() > self.config.height_tolerance
        return torch.where(off[..., None], self.at_height(pixels, heights), lifted)

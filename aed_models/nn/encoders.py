"""Visual heads: one RGB-D frame (4, H, W) -> a feature vector, trained from scratch.

The paper's head is a ResNet18 on 4 x 120 x 160 frames followed by FC 256 and dropout 0.5
(11.3M parameters). It trains at about 40 frames/s on a 2-core CPU, so `small_cnn` gives
the same interface at about ten times the speed for CPU-sized (`mini`) runs. No torchvision:
its wheels do not load beside the CPU build of torch.
"""

from __future__ import annotations

import torch
from torch import nn

from aed_models.nn.config import ARCHS, VisualHeadConfig

__all__ = ["ARCHS", "VisualHeadConfig", "VisualHead", "build_visual_head", "encode_frames"]

IN_CHANNELS = 4  # RGB + depth (see aed_models.data)


class BasicBlock(nn.Module):
    """ResNet's two 3x3 convs with a residual connection (a 1x1 projection when the shape
    changes)."""

    def __init__(self, in_channels: int, channels: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, channels, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(channels)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(channels)
        self.shortcut = nn.Identity()
        if stride != 1 or in_channels != channels:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_channels, channels, 1, stride, bias=False), nn.BatchNorm2d(channels)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = torch.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return torch.relu(out + self.shortcut(x))


class ResNet18(nn.Module):
    """ResNet18 (BasicBlocks [2, 2, 2, 2]) on 4-channel frames, globally average-pooled to 512."""

    out_channels = 512

    def __init__(self, in_channels: int = IN_CHANNELS):
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, 64, 7, 2, 3, bias=False),
            nn.BatchNorm2d(64),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, 2, 1),
        )
        layers, channels = [], 64
        for i, width in enumerate((64, 128, 256, 512)):
            stride = 1 if i == 0 else 2
            layers += [BasicBlock(channels, width, stride), BasicBlock(width, width)]
            channels = width
        self.layers = nn.Sequential(*layers)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(self.stem(x)).mean(dim=(2, 3))


class SpatialSoftmax(nn.Module):
    """Per channel, the expected (x, y) image coordinate under a softmax over pixels.

    Keeps where things are, which global pooling throws away, at no parameter cost.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c, h, w = x.shape
        attention = torch.softmax(x.flatten(2), dim=-1).view(n, c, h, w)
        ys = torch.linspace(-1.0, 1.0, h, device=x.device, dtype=x.dtype)
        xs = torch.linspace(-1.0, 1.0, w, device=x.device, dtype=x.dtype)
        expected_x = (attention.sum(dim=2) * xs).sum(dim=-1)
        expected_y = (attention.sum(dim=3) * ys).sum(dim=-1)
        return torch.cat([expected_x, expected_y], dim=1)


class SmallCNN(nn.Module):
    """Four strided 3x3 convs (/16 overall) -> spatial-softmax keypoints + average pooling."""

    def __init__(self, width: int = 32, in_channels: int = IN_CHANNELS):
        super().__init__()
        widths = (width, width, 2 * width, 2 * width)
        layers, channels = [], in_channels
        for w in widths:
            layers += [
                nn.Conv2d(channels, w, 3, 2, 1),
                nn.GroupNorm(min(8, w), w),
                nn.ReLU(inplace=True),
            ]
            channels = w
        self.convs = nn.Sequential(*layers)
        self.keypoints = SpatialSoftmax()
        self.out_channels = 3 * channels  # (x, y) per channel + the channel's mean

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        maps = self.convs(x)
        return torch.cat([self.keypoints(maps), maps.mean(dim=(2, 3))], dim=1)


class VisualHead(nn.Module):
    """Backbone -> FC `out_dim` -> ReLU -> dropout: (N, 4, H, W) float32 -> (N, out_dim)."""

    def __init__(self, cfg: VisualHeadConfig):
        super().__init__()
        self.cfg = cfg
        self.backbone = ResNet18() if cfg.arch == "resnet18" else SmallCNN(cfg.width)
        self.fc = nn.Linear(self.backbone.out_channels, cfg.out_dim)
        self.dropout = nn.Dropout(cfg.dropout)
        self.out_dim = cfg.out_dim

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        if frames.dim() != 4 or frames.shape[1] != IN_CHANNELS:
            raise ValueError(
                f"frames of shape {tuple(frames.shape)}: expected (N, {IN_CHANNELS}, H, W)"
            )
        if min(frames.shape[-2:]) < 32:
            raise ValueError(f"frames of shape {tuple(frames.shape)}: H and W must be >= 32")
        return self.dropout(torch.relu(self.fc(self.backbone(frames))))


def build_visual_head(cfg: VisualHeadConfig) -> VisualHead:
    """The per-frame encoder `cfg` describes, freshly initialised."""
    return VisualHead(cfg)


def encode_frames(
    head: nn.Module, frames: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """(B, L, 4, H, W) -> (B, L, D); padded frames (mask False) are not encoded and get zeros.

    Skipping padding saves work and keeps it out of BatchNorm's batch statistics.
    """
    b, length = frames.shape[:2]
    if mask is None:
        return head(frames.flatten(0, 1)).view(b, length, -1)
    feats = head(frames[mask])
    out = feats.new_zeros(b, length, feats.shape[-1])
    out[mask] = feats
    return out

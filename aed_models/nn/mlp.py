"""The one MLP builder of the learners."""

from __future__ import annotations

from collections.abc import Sequence

from torch import nn


def mlp(sizes: Sequence[int], out_dim: int | None = None) -> nn.Sequential:
    """Linear + ReLU between consecutive `sizes`, then (when `out_dim` is given) a last Linear
    to `out_dim` with no activation."""
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:], strict=True):
        layers += [nn.Linear(a, b), nn.ReLU()]
    if out_dim is not None:
        layers.append(nn.Linear(sizes[-1], out_dim))
    return nn.Sequential(*layers)

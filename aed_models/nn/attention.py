"""Transformer blocks with an exact incremental (key/value-cached) mode for online use.

`torch.nn.TransformerDecoder` recomputes the whole prefix at every step; here a decoder
layer can also take one new token and a `KVCache` of its past self-attention keys and
values, so step t costs O(t * d) in attention and O(d^2) in projections instead of
O(t * d^2). Post-norm layers (PyTorch's default layout), ReLU feed-forward.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class KVCache:
    """Growing (B, heads, T, head_dim) key and value buffers of one attention layer."""

    def __init__(self) -> None:
        self.keys: torch.Tensor | None = None
        self.values: torch.Tensor | None = None
        self.length = 0

    def append(self, k: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Add (B, heads, n, head_dim) keys and values; returns all of them so far (views)."""
        n = k.shape[2]
        if self.keys is None or self.length + n > self.keys.shape[2]:
            capacity = max(64, 2 * (self.length + n))  # doubling: amortised O(1) per token
            keys, values = (
                k.new_empty(*k.shape[:2], capacity, k.shape[3]),
                v.new_empty(*v.shape[:2], capacity, v.shape[3]),
            )
            if self.keys is not None:
                keys[:, :, : self.length] = self.keys[:, :, : self.length]
                values[:, :, : self.length] = self.values[:, :, : self.length]
            self.keys, self.values = keys, values
        self.keys[:, :, self.length : self.length + n] = k
        self.values[:, :, self.length : self.length + n] = v
        self.length += n
        return self.keys[:, :, : self.length], self.values[:, :, : self.length]


class MultiHeadAttention(nn.Module):
    """Scaled dot-product attention with separate q / k / v projections (so k, v can be cached)."""

    def __init__(self, dim: int, num_heads: int, dropout: float = 0.0):
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"dim={dim} is not divisible by num_heads={num_heads}")
        self.num_heads, self.dropout = num_heads, dropout
        self.q, self.k, self.v, self.out = (nn.Linear(dim, dim) for _ in range(4))

    def split(self, x: torch.Tensor) -> torch.Tensor:
        """(B, T, dim) -> (B, heads, T, head_dim)."""
        b, t, d = x.shape
        return x.view(b, t, self.num_heads, d // self.num_heads).transpose(1, 2)

    def project_kv(self, source: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.split(self.k(source)), self.split(self.v(source))

    def attend(
        self,
        query: torch.Tensor,
        k: torch.Tensor,
        v: torch.Tensor,
        allowed: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """query (B, Tq, dim) over projected k, v; `allowed`
        (bool, broadcast to (B, heads, Tq, Tk))."""
        q = self.split(self.q(query))
        out = F.scaled_dot_product_attention(
            q, k, v, attn_mask=allowed, dropout_p=self.dropout if self.training else 0.0
        )
        return self.out(out.transpose(1, 2).flatten(2))

    def forward(
        self, query: torch.Tensor, source: torch.Tensor, allowed: torch.Tensor | None = None
    ) -> torch.Tensor:
        return self.attend(query, *self.project_kv(source), allowed)


class FeedForward(nn.Sequential):
    def __init__(self, dim: int, hidden: int, dropout: float):
        super().__init__(
            nn.Linear(dim, hidden), nn.ReLU(), nn.Dropout(dropout), nn.Linear(hidden, dim)
        )


class EncoderLayer(nn.Module):
    """Self-attention + feed-forward, post-norm."""

    def __init__(self, dim: int, num_heads: int, ff_dim: int, dropout: float, eps: float):
        super().__init__()
        self.attn = MultiHeadAttention(dim, num_heads, dropout)
        self.ff = FeedForward(dim, ff_dim, dropout)
        self.norm1, self.norm2 = nn.LayerNorm(dim, eps=eps), nn.LayerNorm(dim, eps=eps)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, allowed: torch.Tensor | None = None) -> torch.Tensor:
        x = self.norm1(x + self.drop(self.attn(x, x, allowed)))
        return self.norm2(x + self.drop(self.ff(x)))


class DecoderLayer(nn.Module):
    """Causal self-attention, cross-attention to a memory, feed-forward; post-norm."""

    def __init__(self, dim: int, num_heads: int, ff_dim: int, dropout: float, eps: float):
        super().__init__()
        self.self_attn = MultiHeadAttention(dim, num_heads, dropout)
        self.cross_attn = MultiHeadAttention(dim, num_heads, dropout)
        self.ff = FeedForward(dim, ff_dim, dropout)
        self.norm1, self.norm2, self.norm3 = (nn.LayerNorm(dim, eps=eps) for _ in range(3))
        self.drop = nn.Dropout(dropout)

    def forward(
        self,
        x: torch.Tensor,
        memory_kv: tuple[torch.Tensor, torch.Tensor],
        memory_allowed: torch.Tensor | None,
        cache: KVCache | None = None,
    ) -> torch.Tensor:
        """x (B, T, dim). Without `cache`: all T steps, causally masked. With it: x holds the
        next steps only and attends to the cached past as well (exactly the same result)."""
        k, v = self.self_attn.project_kv(x)
        if cache is None:
            t = x.shape[1]
            causal = torch.ones(t, t, dtype=torch.bool, device=x.device).tril()
        else:
            past = cache.length
            k, v = cache.append(k, v)
            t = x.shape[1]
            causal = torch.ones(t, past + t, dtype=torch.bool, device=x.device).tril(diagonal=past)
        x = self.norm1(x + self.drop(self.self_attn.attend(x, k, v, causal)))
        x = self.norm2(x + self.drop(self.cross_attn.attend(x, *memory_kv, memory_allowed)))
        return self.norm3(x + self.drop(self.ff(x)))


def sinusoid(positions: torch.Tensor, dim: int) -> torch.Tensor:
    """(...,) integer positions -> (..., dim) sinusoidal encodings (Vaswani et al.)."""
    half = dim // 2
    freqs = torch.exp(
        -math.log(10000.0)
        * torch.arange(half, dtype=torch.float32, device=positions.device)
        / max(half, 1)
    )
    angles = positions.to(torch.float32)[..., None] * freqs
    out = torch.cat([angles.sin(), angles.cos()], dim=-1)
    return F.pad(out, (0, dim - 2 * half))


def progress_encoding(progress: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal code of a progress value in [0, 1]: (...,) -> (..., dim).

    Demonstrations have different lengths; coding a frame by its fraction of the episode
    aligns their stages (the rollout is coded by nothing but causal order).
    """
    half = dim // 2
    freqs = torch.exp(
        torch.arange(half, device=progress.device, dtype=progress.dtype)
        * (-math.log(1000.0) / max(half, 1))
    )
    angles = (
        progress[..., None] * (100.0 * math.pi) * freqs
    )  # from 50 cycles per episode down to 0.05
    code = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)
    return F.pad(code, (0, dim - 2 * half))

"""Checkpoints that load without unpickling code: tensors + plain JSON-able data.

A file holds `{"format": FORMAT, "family": ..., "name": ..., "config": dict, "state_dict": ...,
"extra": dict}` and is read with `torch.load(weights_only=True)`. `family` ("policy",
"detector", ...) and `name` (the registry key, e.g. "dct") are checked on load, so a detector
handed to a policy loader, or a `dct` file loaded as `scan`, fails with a clear error instead
of a wall of missing-key messages.
"""

from __future__ import annotations

import os
import pickle
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

FORMAT = "aed-checkpoint/1"


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, not ours, or of another model."""


@dataclass
class Checkpoint:
    family: str
    name: str
    config: dict[str, Any]
    state_dict: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)
    sha256: str = ""


def file_sha256(path: Path | str) -> str:
    from aed_tasks.trajectory import sha256

    return sha256(Path(path))


def save_checkpoint(
    path: Path | str,
    *,
    family: str,
    name: str,
    config: dict[str, Any],
    state_dict: dict[str, Any],
    extra: dict[str, Any] | None = None,
) -> str:
    """Write atomically (a temporary file, then `os.replace`); returns the file's sha256.

    A run killed mid-write leaves the previous checkpoint intact.
    """
    if not isinstance(config, dict):
        raise TypeError(
            f"config of type {type(config).__name__}: must be a plain dict (use dataclasses.asdict)"
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "family": family,
        "name": name,
        "config": config,
        "state_dict": state_dict,
        "extra": dict(extra or {}),
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return file_sha256(path)


def _reason(error: Exception) -> str:
    """The line of torch's message that names the problem: its messages span paragraphs, and
    the one of `weights_only` suggests turning it off."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    named = [line for line in lines if "GLOBAL" in line]
    return (named or lines or [type(error).__name__])[0]


def load_checkpoint(
    path: Path | str, *, family: str, name: str | None = None, map_location: str = "cpu"
) -> Checkpoint:
    """Read and check a checkpoint written by `save_checkpoint`.

    Raises:
        CheckpointError: the file is missing, corrupt or truncated, not an AED checkpoint,
            of another family, or (when `name` is given) of another model.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # torch raises RuntimeError, UnpicklingError, EOFError, ...
        reason = _reason(e)
        if isinstance(e, pickle.UnpicklingError) and "GLOBAL" in reason:  # code: never run it
            raise CheckpointError(
                f"{path}: refused: it holds objects that are not plain tensors and data, and "
                f"loading them could run code ({reason})"
            ) from e
        raise CheckpointError(
            f"{path}: unreadable checkpoint (corrupt or truncated?): {type(e).__name__}: {reason}"
        ) from e
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not an AED checkpoint (no format {FORMAT!r})")
    if payload.get("family") != family:
        raise CheckpointError(
            f"{path}: a {payload.get('family')!r} checkpoint, expected a {family!r} one"
        )
    if name is not None and payload.get("name") != name:
        raise CheckpointError(
            f"{path}: a {family} checkpoint of {payload.get('name')!r}, expected {name!r}"
        )
    for key, kind in (("config", dict), ("state_dict", dict), ("extra", dict), ("name", str)):
        if not isinstance(payload.get(key), kind):
            raise CheckpointError(f"{path}: field {key!r} missing or not a {kind.__name__}")
    return Checkpoint(
        family=payload["family"],
        name=payload["name"],
        config=payload["config"],
        state_dict=payload["state_dict"],
        extra=payload["extra"],
        sha256=file_sha256(path),
    )

"""`aed data-info PATH`: what a collection folder holds (every shard validated on the way)."""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, Literal

import h5py
import numpy as np
import tyro

from aed_tasks import trajectory


def summarize(root: Path, check: trajectory.Check = "quick") -> dict[str, Any]:
    """Counts by role, environment and error kind, lengths per role and outcome, disk size."""
    collection = trajectory.scan_collection(root, check)
    episodes = collection.episodes()
    by_role = Counter(e.role + ("_suboptimal" if e.suboptimal else "") for e in episodes)
    by_env: dict[int, Counter] = defaultdict(Counter)
    for e in episodes:
        by_env[e.env_index][e.role] += 1
    lengths: dict[str, list[int]] = defaultdict(list)
    for e in episodes:
        lengths[e.role].append(e.length)
    outcomes = [e for e in episodes if e.role != "explore"]  # exploration has no outcome
    frames = sum(e.num_frames for e in episodes)
    disk = sum(s.num_bytes for s in collection.shards)
    manifest = trajectory.read_manifest(root) or {}
    return {
        "path": str(root),
        "config": manifest.get("config"),
        "shards": len(collection.shards),
        "episodes": len(episodes),
        "frames": frames,
        "tasks": sorted({e.task for e in episodes}),
        "splits": sorted({e.split for e in episodes}),
        "by_role": dict(sorted(by_role.items())),
        "by_env": {str(k): dict(sorted(v.items())) for k, v in sorted(by_env.items())},
        "error_kinds": dict(
            sorted(Counter(e.error_kind for e in episodes if e.error_kind).items())
        ),
        "lengths": {role: _stats(v) for role, v in sorted(lengths.items())},
        # the same endings for both outcomes: their length distributions should overlap
        "lengths_by_outcome": {
            outcome: _stats([e.length for e in outcomes if e.success == (outcome == "success")])
            for outcome in ("success", "failure")
            if any(e.success == (outcome == "success") for e in outcomes)
        },
        "success_rate": {
            role: float(np.mean([e.success for e in episodes if e.role == role]))
            for role in lengths
        },
        "stages_reached": _stages_reached(outcomes),
        "retries": _retries(collection),
        "disk_bytes": disk,
        "bytes_per_frame": disk / frames if frames else 0.0,
        "leftovers": [p.name for p in collection.temporaries + collection.uncommitted],
    }


def _stages_reached(episodes: list[trajectory.EpisodeRef]) -> dict[str, dict[str, int]]:
    """How far each episode got, by outcome: its highest recorded stage (of `num_stages`).

    The lengths say nothing of a rollout that ran its horizon; this says where it stopped."""
    reached: dict[str, Counter] = defaultdict(Counter)
    by_file: dict[Path, list[trajectory.EpisodeRef]] = defaultdict(list)
    for e in episodes:
        by_file[e.path].append(e)
    for path, refs in by_file.items():
        with h5py.File(path, "r") as h5:
            for e in refs:
                stage = int(h5[f"{e.traj}/stage"][()].max())
                reached["success" if e.success else "failure"][str(stage)] += 1
    return {outcome: dict(sorted(c.items())) for outcome, c in sorted(reached.items())}


def _retries(collection: trajectory.Collection) -> dict[str, Any]:
    """Tries the collection rejected (an expert that could not plan, or missed its role's
    outcome)."""
    entries = [entry for shard in collection.shards for entry in shard.body["episodes"]]
    rejected = sum(int(e.get("attempt", 0)) for e in entries)
    problems = Counter(p[:100] for e in entries for p in e.get("rejected", []))
    return {
        "rejected": rejected,
        "per_episode": rejected / len(entries) if entries else 0.0,
        "problems": dict(problems.most_common(5)),
    }


def _stats(values: list[int]) -> dict[str, float]:
    a = np.asarray(values)
    return {
        "count": len(a),
        "min": int(a.min()),
        "median": float(np.median(a)),
        "mean": float(a.mean()),
        "max": int(a.max()),
    }


def format_summary(info: dict[str, Any]) -> str:
    lines = [
        f"{info['path']}: {info['episodes']} episodes, {info['frames']} frames "
        f"in {info['shards']} shards, {info['disk_bytes'] / 2**20:.1f} MiB "
        f"({info['bytes_per_frame'] / 1024:.1f} KiB/frame)",
        f"tasks {', '.join(info['tasks']) or '-'}; splits {', '.join(info['splits']) or '-'}",
        "by role:        " + _pairs(info["by_role"]),
        "error kinds:    " + _pairs(info["error_kinds"]),
        "lengths (steps, min/median/max):",
    ]
    for role, s in info["lengths"].items():
        lines.append(f"  {role:<16}{_lengths(s)}   success {info['success_rate'][role]:.0%}")
    for outcome, s in info["lengths_by_outcome"].items():
        lines.append(f"  {'all, ' + outcome:<16}{_lengths(s)}")
    for outcome, counts in info["stages_reached"].items():
        lines.append(
            f"stage reached, {outcome + ':':<9}"
            + ", ".join(f"{n} reached {stage}" for stage, n in counts.items())
        )
    retries = info["retries"]
    lines.append(
        f"retries:        {retries['rejected']} rejected tries "
        f"({retries['per_episode']:.2f} per episode)"
        + "".join(f"\n  {n}x {p}" for p, n in retries["problems"].items())
    )
    roles = sorted({r for counts in info["by_env"].values() for r in counts})
    lines.append("by environment: " + " ".join(f"{r:>14}" for r in roles))
    for env, counts in info["by_env"].items():
        lines.append(f"  env {int(env):<10}" + " ".join(f"{counts.get(r, 0):>14}" for r in roles))
    if info["leftovers"]:
        lines.append(
            f"unfinished (interrupted run; re-run aed collect): {', '.join(info['leftovers'])}"
        )
    return "\n".join(lines)


def _lengths(s: dict[str, float]) -> str:
    return f"{s['min']:>5} {s['median']:7.1f} {s['max']:>5}  ({s['count']} episodes)"


def _pairs(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or "-"


def data_info(
    path: tyro.conf.Positional[Path],
    check: Literal["size", "quick", "full"] = "quick",
    as_json: bool = False,
) -> int:
    """Summarise a collection: counts by role, environment, error kind; lengths; disk size.

    Args:
        path: the collection folder (as written by `aed collect`).
        check: size (structure and sizes only), quick or full (also every h5's sha256; the
            same in one command).
        as_json: print JSON instead of a table.
    """
    info = summarize(path, check)
    print(json.dumps(info, indent=2) if as_json else format_summary(info))
    return 0

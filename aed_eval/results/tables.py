"""The policy tables of `results/<profile>/`: every policy's novel success rate beside the
paper's (`scripts/policy_table.py`, the paper's from `aed_eval.paper`), and one policy's variants
paired on the same rollout seeds (`scripts/lever_table.py`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aed_eval.paper import format_rate
from aed_eval.results import command_line, renderer


def _rate(r: dict[str, Any]) -> str:
    low, high = r["interval"]
    return (
        f"{100 * r['success_rate']:.1f}% [{100 * low:.1f}, {100 * high:.1f}] "
        f"({r['successes']}/{r['rollouts']})"
    )


def _data(r: dict[str, Any]) -> str:
    """Training environments x (demonstrations + agent successes) each, where recorded."""
    if "demos_per_env" not in r:  # rows recorded before the counts were
        return f"{r['train_envs']} envs"
    successes = "-".join(str(n) for n in r["successes_per_env"])
    return f"{r['train_envs']} x ({r['demos_per_env']} + {successes})"


def _cost(r: dict[str, Any]) -> str:
    """The policy's epochs and their time, then what its task trained once for every policy."""
    shared = [
        f"{name} {r[f'{name}_seconds'] / 60:.0f} min"
        for name in ("encoder", "localizer")
        if f"{name}_seconds" in r
    ]
    return (
        f"{r['epochs']} epochs, chunks of {r['action_chunk']}, {r['train_seconds'] / 60:.1f} min"
        + (f" (task's {', '.join(shared)})" if shared else "")
    )


def _loss(r: dict[str, Any]) -> str:
    chunked = r.get("action_chunk", 1) > 1 and "own_pos_mse_last" in r
    own = f" ({r['own_pos_mse_last']:.2f})" if chunked else ""
    return f"{r['pos_mse_first']:.2f} -> {r['pos_mse_last']:.2f}{own}"


@renderer("policy_table")
def policy_table(record: dict[str, Any], stem: Path) -> list[Path]:
    """One row per (task, policy): training data and cost, action loss, novel success rate,
    the paper's."""
    lines = [
        "| task | policy | training data: envs x (demos + agent successes) | training "
        "| action loss (share of variance), first -> last 5 epochs (own action's, chunked) "
        "| novel success rate [95%] | paper |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in record["records"]:
        paper = "" if r["paper_success"] is None else format_rate(r["paper_success"])
        lines.append(
            f"| {r['task']} | {r['policy']} | {_data(r)} | {_cost(r)} | {_loss(r)} "
            f"| {_rate(r)} | {paper} |"
        )
    commands: dict[str, list[str]] = {}
    for r in record["records"]:
        if r.get("command") and r["task"] not in commands.setdefault(r["command"], []):
            commands[r["command"]].append(r["task"])
    computed = "".join(f"\nComputed by `{c}` ({', '.join(t)}).\n" for c, t in commands.items())
    path = stem.with_suffix(".md")
    path.write_text("\n".join(lines) + "\n" + (computed or command_line(record)))
    return [path]


@renderer("lever_table")
def lever_table(record: dict[str, Any], stem: Path) -> list[Path]:
    """One row per variant: what it trained on, its action loss, its success rate, and the
    rollouts only it or only the baseline (the first row) succeeded in."""
    lines = [
        f"{record['title']}\n" if record.get("title") else "",
        "| variant | environments x agent successes | epochs (updates) | epochs' time "
        "| action loss (share of variance), first -> last 5 epochs "
        "| novel success rate [95%] | only baseline / only this |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in record["rows"]:
        per_env = "-".join(str(n) for n in r["successes_per_env"])
        lines.append(
            f"| {r['label']} | {r['train_envs']} x {per_env} | {r['epochs']} ({r['updates']}) "
            f"| {r['train_seconds']:.0f} s | {r['pos_mse_first']:.2f} -> {r['pos_mse_last']:.2f} "
            f"| {_rate(r)} | {r['only_baseline']} / {r['only_this']} |"
        )
    path = stem.with_suffix(".md")
    path.write_text("\n".join(line for line in lines if line) + "\n" + command_line(record))
    return [path]

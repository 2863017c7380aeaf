"""`aed models`: the registered policies and detectors with their parameter counts.

Counts are of freshly built models at a profile's sizes, beside the paper's where it gives
one (its attribute table lists the detectors; it gives no policy sizes). Policy-dependent
detectors (PrObe, rnd_oe) are sized by the policy whose features they read, so they get
one row per policy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import tyro


@dataclass
class ModelRow:
    family: str
    name: str
    reads: str  # what it is built on: its own encoder, or a policy's features
    parameters: int
    paper: float | None
    note: str = ""  # why the count differs from the paper's

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": self.family,
            "name": self.name,
            "reads": self.reads,
            "parameters": self.parameters,
            "paper": self.paper,
            "note": self.note,
        }


def count(module: Any) -> int:
    return sum(p.numel() for p in module.parameters())


def model_rows(profile: Literal["mini", "paper"] = "paper") -> list[ModelRow]:
    """Build every registered model at `profile` sizes and count its parameters."""
    from aed_models.detectors import (
        DETECTORS,
        PAPER_NOTES,
        PAPER_PARAMETERS,
        make_detector,
    )
    from aed_models.policies import POLICIES, make_policy

    rows, policies = [], {}
    for name in POLICIES:
        policy = policies[name] = make_policy(name, POLICIES.preset(name, profile))
        rows.append(ModelRow("policy", name, policy.config.visual.arch, count(policy), None))
    for name in DETECTORS:
        config = DETECTORS.preset(name, profile)
        paper, note = PAPER_PARAMETERS.get(name), PAPER_NOTES.get(name, "")
        if make_detector(name, config).requires_policy:
            for policy_name, policy in policies.items():
                dims = {"history_dim": policy.history_dim}
                if hasattr(config, "task_dim"):
                    dims["task_dim"] = policy.task_dim
                detector = make_detector(name, config, **dims)
                rows.append(
                    ModelRow(
                        "detector", name, f"{policy_name} features", count(detector), paper, note
                    )
                )
        else:
            arch = getattr(config, "arch", "own encoder")
            rows.append(
                ModelRow("detector", name, arch, count(make_detector(name, config)), paper, note)
            )
    return rows


def format_rows(rows: list[ModelRow], profile: str) -> str:
    """Markdown table; at paper sizes, differences from the paper are footnoted."""
    notes = {r.name: r.note for r in rows if r.note and profile == "paper"}  # in first-seen order
    marks = {name: f" [{i}]" for i, name in enumerate(notes, 1)}
    lines = [
        f"| family | name | reads | parameters ({profile}) | paper |",
        "|---|---|---|---:|---:|",
    ]
    for r in rows:
        paper = (f"{r.paper / 1e6:.2f}M" if r.paper else "-") + marks.get(r.name, "")
        lines.append(f"| {r.family} | {r.name} | {r.reads} | {r.parameters / 1e6:.2f}M | {paper} |")
    lines += [""] * bool(notes) + [
        f"[{i}] {name}: {note}" for i, (name, note) in enumerate(notes.items(), 1)
    ]
    return "\n".join(lines)


def models(profile: Literal["mini", "paper"] = "paper", as_json: bool = False) -> int:
    """List the registered policies and detectors with parameter counts beside the paper's."""
    import json

    rows = model_rows(profile)
    print(
        json.dumps([r.to_dict() for r in rows], indent=2) if as_json else format_rows(rows, profile)
    )
    return 0


if __name__ == "__main__":
    tyro.cli(models)

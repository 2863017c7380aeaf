"""The error-correction pilot's table (`aed_eval.correction`): the policy's success rate without
a detector and with each one correcting it at its alarms."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aed_eval.metrics import proportion_interval
from aed_eval.paper import format_rate
from aed_eval.results import command_line, renderer


def _rate(successes: int, trials: int) -> str:
    low, high = proportion_interval(successes, trials)
    rate = f"{100 * successes / trials:.1f}% [{100 * low:.1f}, {100 * high:.1f}]"
    return f"{rate} ({successes}/{trials})"


def _paper_rate(rate: list[float] | None) -> str:
    return "not run" if rate is None else format_rate(rate)


@renderer("error_correction")
def render_correction(record: dict[str, Any], stem: Path) -> list[Path]:
    n = record["rollouts"]
    paper = record.get("paper")
    lines = [
        f"Error correction, {record['task']} / {record['policy']}: {n} novel rollouts of "
        f"{record['horizon']} steps replayed with each detector; at an alarm (score >= "
        f"{record['threshold']:g}) the TCP goes above the table centre and the policy resumes.\n",
        "| detector | success rate [95%] | alarmed (on rollouts that had succeeded) "
        "| only without / only with | unalarmed replays whose outcome changed |"
        + (" paper |" if paper else ""),
        "|---|---:|---:|---:|---:|" + ("---:|" if paper else ""),
        f"| none (the stored rollouts) | {_rate(record['successes_without'], n)} | | | |"
        + (f" {_paper_rate(paper['without'])} |" if paper else ""),
    ]
    for d, s in record["detectors"].items():
        lines.append(
            f"| {d} | {_rate(s['successes'], n)} | {s['alarmed']} ({s['alarmed_on_success']}) "
            f"| {s['only_without']} / {s['only_with']} | {s['quiet_replays_changed']} |"
            + (f" {_paper_rate(paper['detectors'].get(d))} |" if paper else "")
        )
    if paper:
        lines += [
            "",
            f"Paper: its {paper['source']}, the success rate's mean +- std over the novel "
            "environments (20 rollouts each); it ran no correction with SVDDED.",
        ]
    md = stem.with_suffix(".md")
    md.write_text("\n".join(lines) + "\n" + command_line(record))
    return [md]

"""The error-correction pilot's table (`aed_eval.correction`): the policy's success rate without
a detector and with each one correcting it at its alarms."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aed_eval.metrics import proportion_interval
from aed_eval.results import command_line, renderer


def _rate(successes: int, trials: int) -> str:
    low, high = proportion_interval(successes, trials)
    rate = f"{100 * successes / trials:.1f}% [{100 * low:.1f}, {100 * high:.1f}]"
    return f"{rate} ({successes}/{trials})"


@renderer("error_correction")
def render_correction(record: dict[str, Any], stem: Path) -> list[Path]:
    n = record["rollouts"]
    lines = [
        f"Error correction, {record['task']} / {record['policy']}: {n} novel rollouts of "
        f"{record['horizon']} steps replayed with each detector; at an alarm (score >= "
        f"{record['threshold']:g}) the TCP goes above the table centre and the policy resumes.\n",
        "| detector | success rate [95%] | alarmed (on rollouts that had succeeded) "
        "| only without / only with | unalarmed replays whose outcome changed |",
        "|---|---:|---:|---:|---:|",
        f"| none (the stored rollouts) | {_rate(record['successes_without'], n)} | | | |",
    ]
    for d, s in record["detectors"].items():
        lines.append(
            f"| {d} | {_rate(s['successes'], n)} | {s['alarmed']} ({s['alarmed_on_success']}) "
            f"| {s['only_without']} / {s['only_with']} | {s['quiet_replays_changed']} |"
        )
    md = stem.with_suffix(".md")
    md.write_text("\n".join(lines) + "\n" + command_line(record))
    return [md]

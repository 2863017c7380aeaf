"""The main experiment's committed cases: one record per (task, policy) under
`results/<profile>/main/` (`aed experiments` writes it when the case's evaluation finishes), and
the paper's main-results report over every case committed there.

A case's numbers live in its record alone (its `aed evaluate` results); the report is a view
of the records beside it, re-rendered with them by `aed results`.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

from aed_eval.results import command_line, renderer

REPORT = "report.md"


@renderer("main_case")
def render_case(record: dict[str, Any], stem: Path) -> list[Path]:
    """The case's evaluation (`aed evaluate`'s Markdown) and the wall time of its jobs; its
    AUROC bars under both endings and its ROC curves (`<stem>_auroc.png`, `<stem>_roc.png`)."""
    from aed_eval.evaluate import format_results
    from aed_eval.report import plot_auroc, plot_roc

    seconds: dict[str, float] = defaultdict(float)
    for job in record["jobs"]:
        seconds[job["stage"]] += job["seconds"]
    times = ", ".join(f"{stage} {s / 60:.1f} min" for stage, s in seconds.items())
    lines = [
        f"# Main experiment: {record['task']} / {record['policy']} (`{record['profile']}`)",
        "",
        format_results(record["results"]),
        "",
        f"Wall time of its {len(record['jobs'])} jobs (the task's shared jobs counted in each of "
        f"its cases): {times}; {sum(seconds.values()) / 60:.0f} min in all.",
    ]
    path = stem.with_suffix(".md")
    path.write_text("\n".join(lines) + "\n" + command_line(record))
    case = record["results"]
    return [
        path,
        plot_auroc(case, stem.with_name(f"{stem.name}_auroc.png")),
        plot_roc(case, stem.with_name(f"{stem.name}_roc.png")),
    ]


def case_records(folder: Path) -> list[tuple[Path, dict[str, Any]]]:
    """Every main case record in `folder`, in the paper's order of tasks and policies."""
    from aed_eval.results import load_record, records_under
    from aed_models.policies import POLICIES
    from aed_tasks import PAPER_TASK_ORDER

    policies = list(POLICIES)
    found = [(p, load_record(p)) for p in records_under(folder) if p.parent == Path(folder)]
    cases = [(p, r) for p, r in found if r["kind"] == "main_case"]
    return sorted(
        cases,
        key=lambda c: (PAPER_TASK_ORDER.index(c[1]["task"]), policies.index(c[1]["policy"])),
    )


def write_main_report(folder: Path, out: Path | None = None) -> Path | None:
    """The paper's main-results report (`aed report`'s tables) over the cases committed in
    `folder`, written to `out` (default `<folder>/report.md`) with its figure beside it
    (`report.png`: every case's AUROC and AUPRC with intervals); None when there is none."""
    from aed_eval.report import build_report, check_cases, plot_overview

    cases = [{**r["results"], "path": str(p)} for p, r in case_records(folder)]
    if not cases:
        return None
    _, text = build_report(cases, check_cases(cases))
    out = Path(out) if out is not None else Path(folder) / REPORT
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    plot_overview(cases, out.with_suffix(".png"))
    return out

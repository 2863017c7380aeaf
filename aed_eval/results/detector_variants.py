"""The ablation tables: every variant's rollout-level AUROC and AUPRC of one (task, policy)
side by side (`aed_eval.variants`), then its time-matched AUROC on the labelled novel episodes,
with their mean and std where the variants are repeats."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from aed_eval.paper import format_rate
from aed_eval.results import command_line, renderer, save_figure


def _cell(c: dict[str, Any], metric: str) -> str:
    value, (low, high) = c[metric], c[f"{metric}_interval"]
    if value is None or not np.isfinite(value):
        return "n/a"
    return f"{value:.3f} [{low:.3f}, {high:.3f}]"


@renderer("detector_variants")
def render_variants(record: dict[str, Any], stem: Path) -> list[Path]:
    """A table per metric (a row per detector, a column per variant) and a bar plot of AUROC."""
    names = list(record["variants"])
    outcomes = ", ".join(
        f"{n}: {v['outcomes']['successes']} successes / {v['outcomes']['failures']} failures"
        for n, v in record["variants"].items()
    )
    lines = [f"{record['title']}: {record['task']} / {record['policy']} ({outcomes}).\n"]
    for metric in ("auroc", "auprc"):
        lines += _table(record, names, "detectors", metric, f"{metric.upper()} [95%]")
    if any("labelled" in v for v in record["variants"].values()):
        lines += [
            "On the labelled novel episodes (expert successes and injected failures; the same "
            "episodes for every variant but a viewpoint's, which sees them through its camera):\n",
            *_table(record, names, "labelled", "time_matched_auroc", "time-matched AUROC [95%]"),
        ]
    if record.get("paper"):
        lines += _beside_paper(record, names)
    md = stem.with_suffix(".md")
    md.write_text("\n".join(lines) + command_line(record))
    return [md, _plot(record, names, Path(f"{stem}.png"))]


def _table(
    record: dict[str, Any], names: list[str], view: str, metric: str, title: str
) -> list[str]:
    """One metric's table: a row per detector, a column per variant (`n/a` where a variant has
    no such cell), the mean and std over the variants where they are repeats."""
    extra = " mean +- std |" if record["spread"] else ""
    lines = [
        f"| {title} | " + " | ".join(names) + f" |{extra}",
        "|---|" + "---:|" * len(names) + ("---:|" if extra else ""),
    ]
    for d in record["detectors"]:
        cells = [record["variants"][n].get(view, {}).get(d) for n in names]
        row = f"| {d} | " + " | ".join("n/a" if c is None else _cell(c, metric) for c in cells)
        row += " |"
        if record["spread"]:
            values = np.asarray([np.nan if c is None else c[metric] for c in cells], dtype=float)
            values = values[np.isfinite(values)]
            spread = np.std(values, ddof=1) if len(values) > 1 else np.nan
            row += f" {np.mean(values):.3f} +- {spread:.3f} |" if len(values) else " n/a |"
        lines.append(row)
    return [*lines, ""]


def _beside_paper(record: dict[str, Any], names: list[str]) -> list[str]:
    """Our point estimates (default ending, and the paper's: stopped at the first success,
    the same metric as its numbers) beside the paper's, for the variants it reports."""
    paper = record["paper"]
    metric = paper["metric"]
    shared = [n for n in names if n in paper["variants"]]
    head = [f"{n}: here | here, paper's ending | paper" for n in shared]
    lines = [
        f"Beside the paper's ({paper['source']}, {metric.upper()}; its policies and detectors at "
        "its sizes, its rollouts stopped at their first success):\n",
        f"| {metric.upper()} | " + " | ".join(head) + " |",
        "|---|" + "---:|---:|---:|" * len(shared),
    ]
    cells = []
    for n in shared:
        outcomes = record["variants"][n]["outcomes"]
        rate = 100 * outcomes["successes"] / (outcomes["successes"] + outcomes["failures"])
        cells.append(f"{rate:.1f}% | | {format_rate(paper['variants'][n]['success_rate'])}")
    lines.append("| policy success rate | " + " | ".join(cells) + " |")
    for d in record["detectors"]:
        cells = []
        for n in shared:
            variant = record["variants"][n]
            ours = [
                _point(variant[view][d][metric]) if view in variant else "n/a"
                for view in ("detectors", "paper_ending")
            ]
            theirs = paper["variants"][n]["detectors"].get(d)
            cells.append(" | ".join([*ours, "-" if theirs is None else f"{theirs:.4f}"]))
        lines.append(f"| {d} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _point(value: float | None) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.3f}"


def _plot(record: dict[str, Any], names: list[str], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    detectors = record["detectors"]
    fig, ax = plt.subplots(figsize=(1.2 * len(detectors) + 2.5, 3.4))
    width = 0.8 / len(names)
    for k, name in enumerate(names):
        cells = [record["variants"][name]["detectors"][d] for d in detectors]
        values = np.asarray([c["auroc"] for c in cells], dtype=float)
        bounds = np.asarray([c["auroc_interval"] for c in cells], dtype=float)
        err = np.nan_to_num(np.stack([values - bounds[:, 0], bounds[:, 1] - values]), nan=0.0)
        x = np.arange(len(detectors)) + (k - (len(names) - 1) / 2) * width
        ax.bar(x, np.nan_to_num(values), width, yerr=err, capsize=2, label=name)
    ax.axhline(0.5, color="grey", linestyle=":")
    ax.set_xticks(np.arange(len(detectors)), detectors, rotation=30, ha="right", fontsize=8)
    ax.set(ylim=(0, 1), ylabel="rollout AUROC [95%]")
    ax.set_title(f"{record['task']} / {record['policy']}: {record['experiment']}", fontsize=9)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return save_figure(fig, path)

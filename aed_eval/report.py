"""`aed report`: the paper's main-results view over any set of (task, policy) evaluations.

From each case's `results.json` and `scores.json` (`aed evaluate`) it writes one folder:
`report.md` / `report.json` (AUROC and AUPRC with intervals under both endings; summary rows
that rank the paper's five detectors only, over cases with at least 5 rollouts of each
outcome; success rates, calibrated rates, detection delays), `overview.png` (every case's
AUROC and AUPRC, the paper's main-results figure) and per case the AUROC, ROC and
score-against-time plots. `≈` marks a best score whose interval overlaps the runner-up's, `‡`
a case too small to rank.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import tyro

from aed_eval import metrics
from aed_eval.evaluate import (
    ENDING_TITLES,
    MIN_PER_OUTCOME,
    labelled_cells,
    too_small,
    with_interval,
)
from aed_eval.paper import POLICY_SUCCESS
from aed_eval.results import save_figure
from aed_eval.scoring import PAPER_DETECTORS
from aed_tasks import trajectory
from aed_tasks.locks import locks_out_folder

logger = logging.getLogger(__name__)

METRICS = ("auroc", "auprc")


@dataclass
class ReportConfig:
    """Which evaluations to gather, and where the report goes."""

    results: tuple[Path, ...] = ()
    """results.json files or eval folders (default: every runs/*/*/eval/results.json)."""
    out: Path = Path("runs/report")
    """Output folder."""
    plots: bool = True
    """Write the PNG plots."""
    paths: list[Path] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        found = [Path(p) / "results.json" if Path(p).is_dir() else Path(p) for p in self.results]
        if not self.results:
            found = sorted(Path("runs").glob("*/*/eval/results.json"))
            if not found:
                raise FileNotFoundError(
                    "runs/*/*/eval/results.json: no evaluations found; run `aed evaluate` first"
                )
        missing = [str(p) for p in found if not p.is_file()]
        if missing:
            raise FileNotFoundError(
                f"{', '.join(missing)}: no such results file (run `aed evaluate`)"
            )
        self.paths = found
        self.out = Path(self.out)


def load_case(path: Path) -> dict[str, Any]:
    try:
        body = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: corrupt results ({e}); re-run aed evaluate") from e
    for key in ("task", "policy", "detectors", "references", "rollouts", "endings"):
        if not isinstance(body, dict) or key not in body:
            raise ValueError(
                f"{path}: not an `aed evaluate` results file of this version (no {key!r}); "
                "re-run aed evaluate"
            )
    body["path"] = str(path)
    return body


def check_cases(cases: list[dict[str, Any]]) -> list[str]:
    """Detectors common to every case; duplicated cases or disjoint detector sets are errors."""
    seen: dict[tuple[str, str], str] = {}
    for case in cases:
        key = (case["task"], case["policy"])
        if key in seen:
            raise ValueError(
                f"{case['path']} and {seen[key]}: two results for {key[0]} / {key[1]}; give one"
            )
        seen[key] = case["path"]
    common = [d for d in cases[0]["detectors"] if all(d in c["detectors"] for c in cases)]
    if not common:
        raise ValueError(
            f"{', '.join(c['path'] for c in cases)}: no detector evaluated in every case"
        )
    for case in cases:
        extra = sorted(set(case["detectors"]) - set(common))
        if extra:
            logger.warning("%s: %s not in every case, left out of the report", case["path"], extra)
    return common


def rankable(case: dict[str, Any], ending: str) -> bool:
    return ending in case["endings"] and not too_small(case["rollouts"]["outcomes"][ending])


def summary_rows(
    cases: list[dict[str, Any]], ranked: list[str], metric: str, ending: str
) -> dict[str, dict[str, float]]:
    """Top-1 counts, average rank and average performance difference of the ranked detectors,
    over the cases large enough to rank."""
    top1 = dict.fromkeys(ranked, 0)
    ranks: dict[str, list[float]] = {d: [] for d in ranked}
    diffs: dict[str, list[float]] = {d: [] for d in ranked}
    for case in cases:
        if not rankable(case, ending):
            continue
        values = np.asarray([case["detectors"][d][ending][metric] for d in ranked], dtype=float)
        if not np.isfinite(values).any():
            continue
        values = np.nan_to_num(values, nan=0.0)
        best, worst = values.max(), values.min()
        order = (-values).argsort(kind="stable")
        rank = np.empty(len(values))
        rank[order] = np.arange(1, len(values) + 1)
        for i, d in enumerate(ranked):
            top1[d] += int(values[i] == best)
            ranks[d].append(float(rank[i]))
            diffs[d].append(float((values[i] - worst) / worst) if worst > 0 else float("nan"))
    return {
        d: {
            "top1": top1[d],
            "avg_rank": float(np.mean(ranks[d])) if ranks[d] else float("nan"),
            "avg_diff": float(np.nanmean(diffs[d]))
            if np.isfinite(diffs[d]).any()
            else float("nan"),
        }
        for d in ranked
    }


def best_marks(cells: dict[str, dict[str, Any]], ranked: list[str], metric: str) -> dict[str, str]:
    """`**` around the best ranked detector; `≈` when its interval overlaps the runner-up's."""
    scored = sorted(
        (d for d in ranked if np.isfinite(cells[d][metric])), key=lambda d: -cells[d][metric]
    )
    if not scored:
        return {}
    marks = {scored[0]: "best"}
    if len(scored) > 1 and metrics.intervals_overlap(
        cells[scored[0]][f"{metric}_interval"], cells[scored[1]][f"{metric}_interval"]
    ):
        marks[scored[0]] = "tied"
    return marks


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}f}"


def metric_table(
    cases: list[dict[str, Any]], names: list[str], detectors: list[str], metric: str, ending: str
) -> tuple[list[str], dict]:
    """One metric under one ending: a row per case, the ranked detectors, then the others."""
    ranked = [d for d in detectors if d in PAPER_DETECTORS]
    others = [d for d in detectors if d not in PAPER_DETECTORS]
    references = list(cases[0]["references"])
    columns = [*ranked, *others, *(f"*{r}*" for r in references)]
    lines = [
        f"### {metric.upper()}, {ENDING_TITLES[ending]}",
        "",
        "| case | " + " | ".join(columns) + " |",
        "|---|" + "---:|" * len(columns),
    ]
    table = {}
    for name, case in zip(names, cases, strict=True):
        if ending not in case["endings"]:
            continue
        cells = {d: case["detectors"][d][ending] for d in detectors}
        cells.update({f"*{r}*": case["references"][r][ending] for r in references})
        table[name] = {
            c: {metric: cells[c][metric], "interval": cells[c][f"{metric}_interval"]}
            for c in columns
        }
        marks = best_marks(cells, ranked, metric)
        texts = []
        for c in columns:
            text = with_interval(cells[c][metric], cells[c][f"{metric}_interval"])
            if c in marks:
                text = f"**{text}**" + (" ≈" if marks[c] == "tied" else "")
            texts.append(text)
        flag = " ‡" if not rankable(case, ending) else ""
        lines.append(f"| {name}{flag} | " + " | ".join(texts) + " |")
    summary = summary_rows(cases, ranked, metric, ending)
    for key, label in (
        ("top1", "Top-1 count"),
        ("avg_rank", "Avg. rank"),
        ("avg_diff", "Avg. perf. diff."),
    ):
        lines.append(
            f"| *{label}* | "
            + " | ".join(_f(summary[d][key], 0 if key == "top1" else 2) for d in ranked)
            + " |" * (1 + len(columns) - len(ranked))
        )
    return lines + [""], {"table": table, "summary": summary}


def build_report(cases: list[dict[str, Any]], detectors: list[str]) -> tuple[dict[str, Any], str]:
    names = [f"{c['task']} / {c['policy']}" for c in cases]
    endings = [e for e in ("horizon", "success") if any(e in c["endings"] for c in cases)]
    report: dict[str, Any] = {
        "cases": names,
        "detectors": detectors,
        "ranked": [d for d in detectors if d in PAPER_DETECTORS],
        "metrics": {},
        "policies": {},
        "calibrated": {},
        "labelled": {},
    }
    lines = [
        "# AED report",
        "",
        "Rollout level, novel environments; 95% bootstrap intervals over rollouts "
        "(resampled within each outcome). Bold: the best of the paper's five detectors, "
        f"`≈` when its interval overlaps the runner-up's. ‡: fewer than {MIN_PER_OUTCOME} "
        "rollouts of an outcome, too small to rank (left out of the summary rows). "
        "rnd_oe and the references stand outside the ranking.",
        "",
    ]
    if any(c.get("diagnostic") for c in cases):
        lines += [
            "**DIAGNOSTIC: some cases were scored on environments a model trained on** "
            f"({', '.join(n for n, c in zip(names, cases, strict=True) if c.get('diagnostic'))}).",
            "",
        ]
    for ending in endings:
        lines += [f"## {ENDING_TITLES[ending].capitalize()}", ""]
        for metric in METRICS:
            table_lines, body = metric_table(cases, names, detectors, metric, ending)
            lines += table_lines
            report["metrics"].setdefault(ending, {})[metric] = body
    lines += [
        "## Policy success rates (novel environments)",
        "",
        (
            "| case | success rate [95%] | successes / rollouts | per environment | paper, per "
            "environment | horizon | median steps success / failure |"
        ),
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, case in zip(names, cases, strict=True):
        r = case["rollouts"]
        sr, lengths = r["success_rate"], r["lengths"][case["ending"]]
        report["policies"][name] = r
        theirs = POLICY_SUCCESS.get(case["task"], {}).get(case["policy"])
        lines.append(
            f"| {name} | {with_interval(100 * sr['rate'], [100 * x for x in sr['interval']], 1)}% "
            f"| {sr['successes']} / {r['count']} | {100 * sr['mean']:.1f} ± {100 * sr['std']:.1f}% "
            f"| {'-' if theirs is None else '{:.1f} ± {:.1f}%'.format(*theirs)} "
            f"| {r['horizon']} | "
            f"{lengths['success'].get('median', '-')} / {lengths['failure'].get('median', '-')} |"
        )
    lines += [
        "",
        "## At the calibrated thresholds",
        "",
        "Calibration `policy@a`: the policy's successful rollouts in held-out base environments, "
        "alpha a; `expert@a`: the expert's successes there (the earlier protocol). FAR: "
        "the false-alarm rate realised on the novel successes [Wilson 95%], to compare with alpha.",
        "",
        "| case | detector | calibration | FAR | TPR | TNR | bal. acc. | detection step |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for name, case in zip(names, cases, strict=True):
        for d in detectors:
            calibrated = case["detectors"][d][case["ending"]].get("calibrated", {})
            report["calibrated"].setdefault(name, {})[d] = calibrated
            for key, rates in calibrated.items():
                lines.append(
                    f"| {name} | {d} | {key} | "
                    f"{with_interval(rates['false_alarm_rate'], rates['false_alarm_interval'], 2)} "
                    f"| {_f(rates['tpr'], 2)} | {_f(rates['tnr'], 2)} | "
                    f"{_f(rates['balanced_accuracy'], 2)} | {_f(rates['detection_step_mean'], 0)} |"
                )
    lines += [
        "",
        "## Labelled novel episodes (expert successes and injected failures)",
        "",
        "Frame AUROC credits a score that grows with time (errors come late); the time-matched "
        "AUROC compares frames of the same 5-step bin only, where `time_only` scores about 0.5.",
        "",
        "| case | detector | frame AUROC [95%] | time-matched AUROC [95%] | delays early/on "
        "time/late/missed |",
        "|---|---|---:|---:|---|",
    ]
    for name, case in zip(names, cases, strict=True):
        rows = [(d, case["detectors"][d].get("labelled")) for d in detectors]
        rows += [(f"*{k}*", v) for k, v in case.get("labelled_references", {}).items()]
        for d, lab in rows:
            if not lab:
                continue
            report["labelled"].setdefault(name, {})[d] = lab
            lines.append(f"| {name} | {d} | {labelled_cells(lab)} |")
    return report, "\n".join(lines) + "\n"


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _bars(ax: Any, series: dict[str, list[dict[str, Any]]], metric: str) -> None:
    """Grouped bars of `metric` with their 95% intervals: one bar per series in each group,
    `series[name][g]` the cell (with `<metric>` and `<metric>_interval`) of group g."""
    width = 0.8 / max(len(series), 1)
    for k, (name, cells) in enumerate(series.items()):
        values = np.asarray([c[metric] for c in cells], dtype=float)
        bounds = np.asarray([c[f"{metric}_interval"] for c in cells], dtype=float)
        err = np.nan_to_num(np.stack([values - bounds[:, 0], bounds[:, 1] - values]), nan=0.0)
        x = np.arange(len(cells)) + (k - (len(series) - 1) / 2) * width
        ax.bar(x, np.nan_to_num(values), width, yerr=err, capsize=2, label=name)


def plot_auroc(case: dict[str, Any], path: Path) -> Path:
    """One case's rollout AUROC with intervals, per detector and reference, under each ending."""
    plt = _pyplot()
    rows = {**case["detectors"], **{f"{k} (ref.)": v for k, v in case["references"].items()}}
    endings = {ENDING_TITLES[e]: [row[e] for row in rows.values()] for e in case["endings"]}
    fig, ax = plt.subplots(figsize=(1.1 * len(rows) + 2, 3.6))
    _bars(ax, endings, "auroc")
    ax.axhline(0.5, color="grey", linestyle=":")
    ax.set_xticks(np.arange(len(rows)), list(rows), rotation=30, ha="right", fontsize=8)
    ax.set(ylim=(0, 1), ylabel="rollout AUROC [95%]", title=f"{case['task']} / {case['policy']}")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_roc(case: dict[str, Any], path: Path) -> Path:
    """One case's ROC curves under its default ending, references dashed."""
    plt = _pyplot()
    rows = {**case["detectors"], **{f"{k} (ref.)": v for k, v in case["references"].items()}}
    fig, ax = plt.subplots(figsize=(4.5, 4.2))
    for name, row in rows.items():
        cell = row[case["ending"]]
        ax.plot(
            cell["roc"]["fpr"],
            cell["roc"]["tpr"],
            "--" if "(ref.)" in name else "-",
            label=f"{name} ({_f(cell['auroc'], 2)})",
        )
    ax.plot([0, 1], [0, 1], ":", color="grey")
    ax.set(
        xlabel="false positive rate",
        ylabel="true positive rate",
        title=f"{case['task']} / {case['policy']}",
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_overview(cases: list[dict[str, Any]], path: Path) -> Path:
    """The paper's main-results figure: AUROC and AUPRC of every detector per (task, policy)
    case with 95% intervals, one row per ending; `time_only` and `random` as lines across
    their case; `‡` where a case has too few of an outcome to rank."""
    plt = _pyplot()
    names = [f"{c['task']}\n{c['policy']}" for c in cases]
    detectors = check_cases(cases)
    endings = [e for e in ENDING_TITLES if all(e in c["endings"] for c in cases)]
    fig, axes = plt.subplots(
        len(endings),
        len(METRICS),
        figsize=(2 + 1.6 * len(cases) * len(METRICS), 3.2 * len(endings)),
        squeeze=False,
    )
    for row, ending in zip(axes, endings, strict=True):
        for ax, metric in zip(row, METRICS, strict=True):
            _bars(ax, {d: [c["detectors"][d][ending] for c in cases] for d in detectors}, metric)
            for ref, style in (("time_only", "-"), ("random", "--")):
                values = [c["references"].get(ref, {}).get(ending, {}).get(metric) for c in cases]
                x = np.asarray([i for i, v in enumerate(values) if v is not None], dtype=float)
                y = [v for v in values if v is not None]
                ax.hlines(
                    y, x - 0.42, x + 0.42, colors="k", linestyles=style, label=f"{ref} (ref.)"
                )
            for i, case in enumerate(cases):
                if not rankable(case, ending):
                    ax.text(i, 0.5, "‡ fewer than 5\nof an outcome", ha="center", fontsize=7)
            if metric == "auroc":
                ax.axhline(0.5, color="grey", linestyle=":")
            ax.set_xticks(np.arange(len(names)), names, fontsize=7)
            ax.set(ylim=(0, 1), ylabel=f"{metric.upper()} [95%]", title=ENDING_TITLES[ending])
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=7)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return save_figure(fig, path)


def plot_scores(case: dict[str, Any], path: Path) -> Path | None:
    """Score against time of every detector on one successful and one failed episode (the
    labelled novel episodes when scored, else the rollouts), from the case's `scores.json`."""
    scores_path = Path(case["path"]).with_name("scores.json")
    if not scores_path.exists():
        logger.warning("%s: missing, no score-vs-time plot", scores_path)
        return None
    try:
        scored = json.loads(scores_path.read_text())
        group = (
            scored["labelled"] if scored.get("labelled", {}).get("episodes") else scored["rollouts"]
        )
        episodes, scores = group["episodes"], group["scores"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        logger.warning("%s: unreadable (%s), no score-vs-time plot", scores_path, e)
        return None
    plt = _pyplot()
    success = next((i for i, e in enumerate(episodes) if e["success"]), None)
    failure = next((i for i, e in enumerate(episodes) if not e["success"]), None)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=False)
    for ax, index, title in ((axes[0], success, "successful"), (axes[1], failure, "failed")):
        if index is None:
            ax.set_title(f"no {title} episode")
            continue
        for name, values in scores.items():
            ax.plot(values[index], label=name)
        onset = episodes[index].get("onset_frame")
        if onset is not None:
            ax.axvline(onset, color="red", linestyle="--", label="labelled onset")
        ax.set(
            xlabel="frame",
            ylabel="score",
            title=f"{title} episode (env {episodes[index]['env_index']})",
        )
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_case(case: dict[str, Any], out: Path) -> list[Path]:
    """AUROC with intervals per ending, ROC curves, and score against time for two episodes."""
    stem = f"{case['task']}_{case['policy']}"
    written = [plot_auroc(case, out / f"auroc_{stem}.png"), plot_roc(case, out / f"roc_{stem}.png")]
    scores = plot_scores(case, out / f"scores_{stem}.png")
    return written + ([scores] if scores else [])


@locks_out_folder  # one report per out folder (aed_tasks.locks)
def make_report(cfg: ReportConfig) -> Path:
    cases = [load_case(p) for p in cfg.paths]
    detectors = check_cases(cases)
    report, text = build_report(cases, detectors)
    cfg.out.mkdir(parents=True, exist_ok=True)
    if cfg.plots:
        plots = [plot_overview(cases, cfg.out / "overview.png")]
        plots += [p for c in cases for p in plot_case(c, cfg.out)]
        report["plots"] = [str(p) for p in plots]
    trajectory.write_json_atomic(cfg.out / "report.json", report)
    (cfg.out / "report.md").write_text(text)
    return cfg.out / "report.md"


def report(cfg: Annotated[ReportConfig, tyro.conf.arg(name="")]) -> int:
    """Gather `aed evaluate` results into the paper's main-results view (Markdown, JSON, PNG)."""
    path = make_report(cfg)
    print(path.read_text())
    print(path)
    return 0

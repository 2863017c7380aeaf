"""`aed report`: the paper's main-results view over any set of (task, policy) evaluations.

Reads the `results.json` (and `scores.json`) that `aed evaluate` wrote for each case and
writes, into one folder:

- `report.md` / `report.json`: AUROC and AUPRC per case and detector (the reference rows
  `time_only` and `random` beside them), Top-1 counts, average rank and average performance
  difference `(score - worst) / worst` per detector (the paper's summary rows), the policies'
  success rates, the rates at each calibrated threshold, and detection delays on labelled
  episodes;
- `roc_<task>_<policy>.png`: ROC curves of every detector for one case;
- `scores_<task>_<policy>.png`: score against time for a successful and a failed episode per
  detector, the labelled onset marked when the failed episode has one.
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
from aed_tasks import trajectory

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
                raise FileNotFoundError("runs/*/*/eval/results.json: no evaluations found; run `aed evaluate` first")
        missing = [str(p) for p in found if not p.is_file()]
        if missing:
            raise FileNotFoundError(f"{', '.join(missing)}: no such results file (run `aed evaluate`)")
        self.paths = found
        self.out = Path(self.out)


def load_case(path: Path) -> dict[str, Any]:
    try:
        body = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: corrupt results ({e}); re-run aed evaluate") from e
    for key in ("task", "policy", "detectors", "references", "rollouts"):
        if key not in body:
            raise ValueError(f"{path}: not an `aed evaluate` results file (no {key!r})")
    body["path"] = str(path)
    return body


def check_cases(cases: list[dict[str, Any]]) -> list[str]:
    """Detectors common to every case; duplicated cases or disjoint detector sets are errors."""
    seen: dict[tuple[str, str], str] = {}
    for case in cases:
        key = (case["task"], case["policy"])
        if key in seen:
            raise ValueError(f"{case['path']} and {seen[key]}: two results for {key[0]} / {key[1]}; give one")
        seen[key] = case["path"]
    common = [d for d in cases[0]["detectors"] if all(d in c["detectors"] for c in cases)]
    if not common:
        raise ValueError(f"{', '.join(c['path'] for c in cases)}: no detector evaluated in every case")
    for case in cases:
        extra = sorted(set(case["detectors"]) - set(common))
        if extra:
            logger.warning("%s: %s not in every case, left out of ranks", case["path"], extra)
    return common


def summary_rows(cases: list[dict[str, Any]], detectors: list[str], metric: str) -> dict[str, dict[str, float]]:
    """Top-1 counts, average rank and average performance difference of each detector."""
    top1 = dict.fromkeys(detectors, 0)
    ranks: dict[str, list[float]] = {d: [] for d in detectors}
    diffs: dict[str, list[float]] = {d: [] for d in detectors}
    for case in cases:
        values = np.asarray([case["detectors"][d][metric] for d in detectors], dtype=float)
        if not np.isfinite(values).any():
            continue  # undefined here (e.g. no successful rollout): the case does not rank anyone
        values = np.nan_to_num(values, nan=0.0)
        best, worst = values.max(), values.min()
        order = (-values).argsort(kind="stable")
        rank = np.empty(len(values))
        rank[order] = np.arange(1, len(values) + 1)
        for i, d in enumerate(detectors):
            top1[d] += int(values[i] == best)
            ranks[d].append(float(rank[i]))
            diffs[d].append(float((values[i] - worst) / worst) if worst > 0 else float("nan"))
    return {d: {"top1": top1[d], "avg_rank": float(np.mean(ranks[d])) if ranks[d] else float("nan"),
                "avg_diff": float(np.nanmean(diffs[d])) if np.isfinite(diffs[d]).any() else float("nan")}
            for d in detectors}  # fmt: skip


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}f}"


def build_report(cases: list[dict[str, Any]], detectors: list[str]) -> tuple[dict[str, Any], str]:
    names = [f"{c['task']} / {c['policy']}" for c in cases]
    report: dict[str, Any] = {"cases": names, "detectors": detectors, "metrics": {}, "summary": {}, "policies": {},
                              "calibrated": {}, "delays": {}}  # fmt: skip
    lines = ["# AED report", ""]
    for metric in METRICS:
        columns = [*detectors, *(f"*{r}*" for r in cases[0]["references"])]
        lines += [f"## {metric.upper()} (rollout level, novel environments)", "",
                  "| case | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]  # fmt: skip
        table = {}
        for name, case in zip(names, cases, strict=True):
            row = {d: case["detectors"][d][metric] for d in detectors}
            row.update({f"*{r}*": v[metric] for r, v in case["references"].items()})
            table[name] = row
            best = max((row[d] for d in detectors if np.isfinite(row[d])), default=None)
            cells = [f"**{_f(row[c])}**" if c in detectors and row[c] == best else _f(row[c]) for c in columns]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        summary = summary_rows(cases, detectors, metric)
        for key, label in (("top1", "Top-1 count"), ("avg_rank", "Avg. rank"), ("avg_diff", "Avg. perf. diff.")):
            lines.append(f"| *{label}* | " + " | ".join(_f(summary[d][key], 0 if key == "top1" else 2) for d in detectors)
                         + " |" * (1 + len(columns) - len(detectors)))  # fmt: skip
        report["metrics"][metric], report["summary"][metric] = table, summary
        lines.append("")
    lines += ["## Policy success rates (novel environments)", "", "| case | success rate | rollouts | median frames success / failure |",
              "|---|---:|---:|---|"]  # fmt: skip
    for name, case in zip(names, cases, strict=True):
        r = case["rollouts"]
        sr = r["success_rate"]
        report["policies"][name] = r
        lines.append(f"| {name} | {100 * sr['mean']:.1f} ± {100 * sr['std']:.1f}% | {r['count']} | "
                     f"{r['lengths']['success'].get('median', '-')} / {r['lengths']['failure'].get('median', '-')} |")  # fmt: skip
    lines += ["", "## At the calibrated threshold (rollout level) and on labelled episodes", "",
              "| case | detector | alpha | TPR | TNR | bal. acc. | frame AUROC | delays early/on time/late/missed |",
              "|---|---|---:|---:|---:|---:|---:|---|"]  # fmt: skip
    for name, case in zip(names, cases, strict=True):
        for d in detectors:
            row = case["detectors"][d]
            cal, lab = row.get("calibrated", {}), row.get("labelled", {})
            counts = lab.get("delays", {}).get("counts")
            report["calibrated"].setdefault(name, {})[d] = cal
            report["delays"].setdefault(name, {})[d] = lab
            lines.append(f"| {name} | {d} | {_f(cal.get('alpha'), 2)} | {_f(cal.get('tpr'), 2)} | {_f(cal.get('tnr'), 2)} | "
                         f"{_f(cal.get('balanced_accuracy'), 2)} | {_f(lab.get('frame_auroc'))} | "
                         + ("/".join(str(counts[k]) for k in metrics.DELAY_CLASSES) if counts else "-") + " |")  # fmt: skip
    return report, "\n".join(lines) + "\n"


def plot_case(case: dict[str, Any], out: Path) -> list[Path]:
    """ROC curves of a case, and score against time for a successful and a failed episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stem = f"{case['task']}_{case['policy']}"
    written = []
    fig, ax = plt.subplots(figsize=(4.5, 4.2))
    for name, row in [*case["detectors"].items(), *case["references"].items()]:
        style = "--" if name in case["references"] else "-"
        ax.plot(row["roc"]["fpr"], row["roc"]["tpr"], style, label=f"{name} ({_f(row['auroc'], 2)})")
    ax.plot([0, 1], [0, 1], ":", color="grey")
    ax.set(xlabel="false positive rate", ylabel="true positive rate", title=f"{case['task']} / {case['policy']}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    written.append(out / f"roc_{stem}.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    scores_path = Path(case["path"]).with_name("scores.json")
    if not scores_path.exists():
        logger.warning("%s: missing, no score-vs-time plot", scores_path)
        return written
    scored = json.loads(scores_path.read_text())
    group = scored.get("labelled") if scored.get("labelled", {}).get("episodes") else scored["rollouts"]
    episodes = group["episodes"]
    success = next((i for i, e in enumerate(episodes) if e["success"]), None)
    failure = next((i for i, e in enumerate(episodes) if not e["success"]), None)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=False)
    for ax, index, title in ((axes[0], success, "successful"), (axes[1], failure, "failed")):
        if index is None:
            ax.set_title(f"no {title} episode")
            continue
        for name, values in group["scores"].items():
            ax.plot(values[index], label=name)
        onset = episodes[index].get("onset_frame")
        if onset is not None:
            ax.axvline(onset, color="red", linestyle="--", label="labelled onset")
        ax.set(xlabel="frame", ylabel="score", title=f"{title} episode (env {episodes[index]['env_index']})")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    written.append(out / f"scores_{stem}.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)
    return written


def make_report(cfg: ReportConfig) -> Path:
    cases = [load_case(p) for p in cfg.paths]
    detectors = check_cases(cases)
    report, text = build_report(cases, detectors)
    cfg.out.mkdir(parents=True, exist_ok=True)
    if cfg.plots:
        report["plots"] = [str(p) for c in cases for p in plot_case(c, cfg.out)]
    trajectory.write_json_atomic(cfg.out / "report.json", report)
    (cfg.out / "report.md").write_text(text)
    return cfg.out / "report.md"


def report(cfg: Annotated[ReportConfig, tyro.conf.arg(name="")]) -> int:
    """Gather `aed evaluate` results into the paper's main-results view (Markdown, JSON, PNG)."""
    path = make_report(cfg)
    print(path.read_text())
    print(path)
    return 0

"""Results as data: every table and plot under `results/` is rendered from the JSON beside it.

An experiment's script computes one record, a JSON object whose `kind` names its renderer, and
`write_result` stores it (atomically) and renders its Markdown and plots from the record alone:
nothing under `results/` is edited by hand. `aed results` re-renders every record under a folder;
`aed results --check` renders into a scratch folder instead and names every Markdown file that
differs from the one committed (a table edited by hand, or a renderer changed without
re-rendering). Plots are compared only with `--figures`: their bytes depend on matplotlib's
version and the fonts' rendering, so they are identical on one environment, not across all.
"""

from __future__ import annotations

import json
import logging
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import tyro

from aed_tasks import trajectory

logger = logging.getLogger(__name__)

Renderer = Callable[[dict[str, Any], Path], list[Path]]
"""(record, stem) -> the files written: `<stem>.md` and any `<stem>*.png` beside it."""

_RENDERERS: dict[str, Renderer] = {}


def renderer(kind: str) -> Callable[[Renderer], Renderer]:
    """Register the renderer of the records of one `kind`."""

    def register(fn: Renderer) -> Renderer:
        if kind in _RENDERERS:
            raise ValueError(f"results kind {kind!r} registered twice")
        _RENDERERS[kind] = fn
        return fn

    return register


def renderers() -> dict[str, Renderer]:
    """Every kind's renderer (importing the modules that register them)."""
    from aed_eval.results import (  # noqa: F401
        correction,
        detector_variants,
        embeddings,
        main,
        success_window,
        tables,
        timing,
    )

    return dict(_RENDERERS)


def load_record(path: Path) -> dict[str, Any]:
    """A results record, checked: a JSON object whose `kind` has a renderer."""
    try:
        record = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a readable JSON results record ({e})") from e
    if not isinstance(record, dict) or "kind" not in record:
        raise ValueError(f"{path}: not a results record (a JSON object with a 'kind')")
    known = renderers()
    if record["kind"] not in known:
        raise ValueError(f"{path}: unknown results kind {record['kind']!r}; known {sorted(known)}")
    return record


def render_record(record: dict[str, Any], stem: Path) -> list[Path]:
    """Write the Markdown and plots of one record at `stem` (a path without suffix)."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    return renderers()[record["kind"]](record, stem)


def write_result(path: Path, record: dict[str, Any]) -> list[Path]:
    """Store a record as JSON at `path` (atomically), then render it beside; returns every file
    written, the JSON first."""
    path = Path(path)
    if record.get("kind") not in renderers():
        raise ValueError(f"record kind {record.get('kind')!r}: known {sorted(renderers())}")
    path.parent.mkdir(parents=True, exist_ok=True)
    trajectory.write_json_atomic(path, record)
    return [path, *render_record(load_record(path), path.with_suffix(""))]


def records_under(root: Path) -> list[Path]:
    """Every results record under `root` (JSON files with a `kind`), sorted; other JSON files
    (benchmarks' raw output, the evaluation's own files) are not records and are skipped."""
    found = []
    for path in sorted(Path(root).rglob("*.json")):
        try:
            body = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        if isinstance(body, dict) and "kind" in body:
            found.append(path)
    return found


def stale_markdown(root: Path, figures: bool = False) -> list[str]:
    """Render every record under `root` into a scratch folder; one line for each Markdown file
    (and with `figures` each plot, byte for byte) that differs from (or is missing beside) its
    record."""
    from aed_eval.results.main import REPORT, write_main_report

    compared = (".md", ".png") if figures else (".md",)
    problems = []
    with tempfile.TemporaryDirectory() as scratch:
        for path in records_under(root):
            stem = Path(scratch) / path.relative_to(root).with_suffix("")
            for written in render_record(load_record(path), stem):
                if written.suffix in compared:
                    problems += _differs(
                        written, path.parent / written.name, f"what {path} renders to"
                    )
        for folder in main_folders(root):
            report = write_main_report(folder, Path(scratch) / folder.relative_to(root) / REPORT)
            for suffix in compared:
                written = report.with_suffix(suffix)
                committed = (folder / REPORT).with_suffix(suffix)
                problems += _differs(written, committed, "what the cases beside it render to")
    return problems


def _differs(written: Path, committed: Path, source: str) -> list[str]:
    if not committed.exists():
        return [f"{committed}: missing ({source})"]
    if committed.read_bytes() != written.read_bytes():
        return [f"{committed}: differs from {source}"]
    return []


def main_folders(root: Path) -> list[Path]:
    """The folders under `root` that hold main experiment cases (`aed_eval.results.main`)."""
    folders = {p.parent for p in records_under(root) if load_record(p)["kind"] == "main_case"}
    return sorted(folders)


@dataclass
class ResultsConfig:
    """Re-render (or check) every results record under some folders.

    Args:
        roots: folders searched for records (JSON files with a `kind`).
        check: render into a scratch folder and list the Markdown files that differ from the
            committed ones (exit status 1 if any); write nothing.
        figures: with `check`, compare the plots too, byte for byte (identical on the
            environment that rendered them; another matplotlib may draw other bytes).
    """

    roots: tuple[Path, ...] = (Path("results"),)
    check: bool = False
    figures: bool = False

    def __post_init__(self) -> None:
        missing = [str(r) for r in self.roots if not Path(r).is_dir()]
        if missing:
            raise ValueError(f"roots: no such folder {missing}")


def results(cfg: Annotated[ResultsConfig, tyro.conf.arg(name="")]) -> int:
    """Regenerate every table and plot under `results/` from the JSON beside it."""
    if cfg.check:
        problems = [line for root in cfg.roots for line in stale_markdown(root, cfg.figures)]
        count = sum(len(records_under(root)) for root in cfg.roots)
        what = "table and plot" if cfg.figures else "table"
        print("\n".join(problems) if problems else f"{count} records: every {what} as rendered")
        return 1 if problems else 0
    from aed_eval.results.main import write_main_report

    for root in cfg.roots:
        for path in records_under(root):
            written = render_record(load_record(path), path.with_suffix(""))
            print(f"{path}: {', '.join(p.name for p in written)}")
        for folder in main_folders(root):
            print(f"{write_main_report(folder)}: the report over the cases beside it")
    return 0


def command_line(record: dict[str, Any]) -> str:
    """The Markdown line naming the command that computed a record, if it says."""
    return f"\nComputed by `{record['command']}`.\n" if record.get("command") else ""


def save_figure(fig: Any, path: Path) -> Path:
    """Save a matplotlib figure without the metadata that changes from run to run."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=120, metadata={"Software": None})
    plt.close(fig)
    return path

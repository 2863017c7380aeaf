"""The embedding figure's table and plot (`aed_eval.embeddings`): one t-SNE panel per detector,
normal frames green and error frames red, darker early in the episode and brighter late."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from aed_eval.results import command_line, renderer, save_figure

NORMAL, ERROR = np.array([0.1, 0.65, 0.2]), np.array([0.85, 0.1, 0.1])


def frame_colours(episodes: list[dict[str, Any]]) -> np.ndarray:
    """(N, 3) colour of every frame: its label's, scaled from 0.35 (first frame) to 1 (last)."""
    colours = []
    for e in episodes:
        onset = e["onset_frame"]
        for i in range(e["frames"]):
            base = ERROR if onset is not None and i >= onset else NORMAL
            colours.append(base * (0.35 + 0.65 * i / max(e["frames"] - 1, 1)))
    return np.clip(np.asarray(colours), 0.0, 1.0)


def plot(record: dict[str, Any], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = frame_colours(record["episodes"])
    names = list(record["detectors"])
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        points = np.asarray(record["detectors"][name]["points"])
        ax.scatter(points[:, 0], points[:, 1], c=colours, s=6, linewidths=0)
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{record['task']} / {record['policy']}: t-SNE of the detectors' embeddings")
    fig.tight_layout()
    return save_figure(fig, path)


@renderer("embeddings")
def render_embeddings(record: dict[str, Any], stem: Path) -> list[Path]:
    episodes = record["episodes"]
    failures = sum(e["onset_frame"] is not None for e in episodes)
    k = record["neighbours"]
    png = plot(record, stem.with_name(stem.name + ".png"))
    lines = [
        f"Embeddings, {record['task']} / {record['policy']}: {len(episodes)} labelled novel "
        f"episodes ({len(episodes) - failures} successes, {failures} failures; "
        f"{sum(e['frames'] for e in episodes)} frames), t-SNE with perplexity "
        f"{record['perplexity']:g}, seed {record['seed']}.\n",
        f"![t-SNE of the embeddings]({png.name})\n",
        f"Measured in the embeddings themselves, over each frame's {k} nearest frames of other "
        "episodes:\n",
        "| detector | embedding size | same label (normal / error) | same label by chance "
        "| mean progress gap |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, d in record["detectors"].items():
        lines.append(
            f"| {name} | {d['dim']} | {d['label_agreement']:.3f} | {d['chance']:.3f} "
            f"| {d['progress_gap']:.3f} |"
        )
    md = stem.with_suffix(".md")
    md.write_text("\n".join(lines) + "\n" + command_line(record))
    return [md, png]

"""Where the protocol's files live: one convention under a runs folder (default `runs/`).

runs/<task>/data/<split>                       aed collect (base: training; novel: demonstrations)
runs/<task>/data/<split>-labelled              labelled expert episodes of the novel split
runs/<task>/encoder/encoder.pt                 aed train-encoder (the mini policies' frozen head)
runs/<task>/localizer/localizer.pt             aed train-localizer (the mini policies' targets)
runs/<task>/policies/<policy>/policy.pt        aed train-policy
runs/<task>/detectors/<detector>[-<policy>]/   aed train-detector (detector.pt), aed calibrate
runs/<task>/features/<policy sha256[:16]>/seed<s>-demos<n>/  frozen-policy features (PrObe, rnd_oe)
runs/<task>/rollouts/<policy>/<split>          aed rollout
runs/<task>/<policy>/eval                      aed evaluate
runs/report                                    aed report
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RunLayout:
    root: Path = Path("runs")

    def data(self, task: str, split: str = "base") -> Path:
        return Path(self.root) / task / "data" / split

    def labelled(self, task: str, split: str = "novel") -> Path:
        return Path(self.root) / task / "data" / f"{split}-labelled"

    def encoder(self, task: str) -> Path:
        return Path(self.root) / task / "encoder" / "encoder.pt"

    def localizer(self, task: str) -> Path:
        return Path(self.root) / task / "localizer" / "localizer.pt"

    def policy(self, task: str, policy: str) -> Path:
        return Path(self.root) / task / "policies" / policy / "policy.pt"

    def detector(self, task: str, detector: str, policy: str) -> Path:
        """Policy-dependent detectors are trained per policy: `<detector>-<policy>`."""
        from aed_models.detectors import requires_policy

        suffix = f"-{policy}" if requires_policy(detector) else ""
        return Path(self.root) / task / "detectors" / f"{detector}{suffix}" / "detector.pt"

    def features(self, task: str) -> Path:
        """Cached features of frozen policies, one folder per policy checkpoint."""
        return Path(self.root) / task / "features"

    def rollouts(self, task: str, policy: str, split: str = "novel") -> Path:
        return Path(self.root) / task / "rollouts" / policy / split

    def evaluation(self, task: str, policy: str) -> Path:
        return Path(self.root) / task / policy / "eval"

    def report(self) -> Path:
        return Path(self.root) / "report"

"""Variants beside the main experiment: the paper's ablations, its stability runs and its
demonstration-quality and viewpoint-shift experiments.

A detector experiment changes only the detectors: how each trains (`augment`, `seed`) or its
model (PrObe's components). A rollout experiment changes what the trained policies and
detectors are given in the novel environments (sub-optimal demonstrations, or every novel
episode seen through another camera): the policies roll out again and the detectors score
those rollouts. Each variant runs in its own runs folder,
`<runs>/variants/<experiment>/<variant>/`, whose task folder links the main run's parts it
does not change (collections, scene encoder, localizer, policies, feature caches; rollouts or
detectors) and holds its own (detectors or rollouts, then calibrations and evaluations): every
stage reads it through the same `RunLayout`, and nothing the main experiment wrote is touched.
The baseline variant is the main experiment itself (no jobs). Its record
(`results/<profile>/<experiment>/<task>_<policy>.json`, kind `detector_variants`) puts every
variant's outcomes and rollout-level AUROC and AUPRC side by side, with the time-matched AUROC
on the labelled novel episodes (which does not depend on how often the policy succeeds).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aed_eval import paper
from aed_eval.scoring import DETECTOR_NAMES
from aed_models.layout import RunLayout

logger = logging.getLogger(__name__)

DETECTOR_SHARED = ("data", "encoder", "localizer", "policies", "rollouts", "features")
"""What a detector variant's task folder links from the main run (all but detectors and evals)."""
ROLLOUT_SHARED = ("data", "encoder", "localizer", "policies", "detectors", "features")
"""What a rollout variant's task folder links (all but rollouts and evaluations)."""
SUBOPTIMAL = "novel-suboptimal"
"""`<runs>/<task>/data/<this>`: the novel environments' sub-optimal demonstrations."""


def camera_data(camera: str) -> str:
    """`<runs>/<task>/data/<this>`: the novel environments' demonstrations and labelled
    episodes recorded through `camera`."""
    return f"novel-{camera}"


@dataclass(frozen=True)
class Variant:
    """One variant: its label, the detector-training fields it changes, the detector-model
    fields it changes, the sub-optimal demonstrations among the novel ones it gives the policy
    and the detectors ("all": every one), the camera every novel episode is seen through (the
    models trained on `front`), or `baseline`: the main experiment itself."""

    name: str
    training: dict[str, Any] = field(default_factory=dict)
    model: dict[str, Any] = field(default_factory=dict)
    suboptimal_demos: int | str = 0
    camera: str = "front"
    baseline: bool = False

    @property
    def rolls_out(self) -> bool:
        """The policies roll out again (other demonstrations, or another camera)."""
        return bool(self.suboptimal_demos) or self.camera != "front"

    def num_suboptimal(self, num_demos: int) -> int:
        n = self.suboptimal_demos
        return num_demos if n == "all" else min(int(n), num_demos)


@dataclass(frozen=True)
class DetectorExperiment:
    """Detectors of some policies on some tasks, under several variants."""

    name: str
    title: str
    tasks: tuple[str, ...]
    policies: tuple[str, ...]
    detectors: tuple[str, ...]
    variants: tuple[Variant, ...]
    spread: bool = False  # the variants are repeats (seeds): also report their mean and std


EXPERIMENTS = {
    e.name: e
    for e in (
        DetectorExperiment(
            "rollout_augmentation",
            "Rollout augmentation (RA): every detector trained without and with it",
            tasks=("PickPlace",),
            policies=("naive_dc", "dct", "scan"),
            detectors=DETECTOR_NAMES,
            variants=(Variant("without RA", {"augment": False}), Variant("with RA", baseline=True)),
        ),
        DetectorExperiment(
            "probe_components",
            "PrObe's components: the naive model, then the pattern extractor, L_pat and L_tem",
            tasks=("PickPlace",),
            policies=("scan",),
            detectors=("probe",),
            variants=(
                Variant(
                    "naive model",
                    model={"use_pattern_extractor": False, "lambda_pat": 0.0, "lambda_tem": 0.0},
                ),
                Variant("+ pattern extractor", model={"lambda_pat": 0.0, "lambda_tem": 0.0}),
                Variant("+ L_pat", model={"lambda_tem": 0.0}),
                Variant("+ L_tem (PrObe)", baseline=True),
            ),
        ),
        DetectorExperiment(
            "seeds",
            "Stability: every detector trained with five seeds",
            tasks=("PickPlace",),
            policies=("naive_dc", "dct", "scan"),
            detectors=DETECTOR_NAMES,
            variants=(
                Variant("seed 0", baseline=True),
                *(Variant(f"seed {s}", {"seed": s}) for s in range(1, 5)),
            ),
            spread=True,
        ),
        DetectorExperiment(
            "demo_quality",
            "Demonstration quality: the policies and detectors given sub-optimal demonstrations",
            tasks=("PressButton",),
            policies=("naive_dc", "dct", "scan"),
            detectors=DETECTOR_NAMES,
            variants=(
                Variant("all optimal", baseline=True),
                Variant("2 sub-optimal", suboptimal_demos=2),
                Variant("all sub-optimal", suboptimal_demos="all"),
            ),
        ),
        DetectorExperiment(
            "viewpoint",
            "Viewpoint shift: the policy and detectors trained on `front`, deployed through "
            "`front_shift`",
            tasks=("PressButton",),
            policies=("dct",),
            detectors=DETECTOR_NAMES,
            variants=(
                Variant("front", baseline=True),
                Variant("front_shift", camera="front_shift"),
            ),
        ),
    )
}


def variant_root(runs: Path, experiment: str, variant: Variant) -> Path:
    """The runs folder of one variant (the main run's own for the baseline)."""
    if variant.baseline:
        return Path(runs)
    slug = "".join(c if c.isalnum() else "_" for c in variant.name).strip("_")
    return Path(runs) / "variants" / experiment / slug


@dataclass
class LinkConfig:
    """Link a variant's task folder to the main run's shared parts."""

    main: Path
    variant: Path
    task: str
    parts: tuple[str, ...] = DETECTOR_SHARED


def link_shared(cfg: LinkConfig) -> None:
    """Make `<variant>/<task>/<part>` a link to the main run's, for every shared part (relative
    links, so the runs folder can move); an existing different file or link is refused."""
    folder = Path(cfg.variant) / cfg.task
    folder.mkdir(parents=True, exist_ok=True)
    for part in cfg.parts:
        target = Path(cfg.main) / cfg.task / part
        target.mkdir(parents=True, exist_ok=True)  # features may not exist yet
        link = folder / part
        relative = os.path.relpath(target, folder)
        if link.is_symlink() and os.readlink(link) == relative:
            continue
        if link.exists() or link.is_symlink():
            raise FileExistsError(f"{link}: exists and is not a link to {target}; move it away")
        link.symlink_to(relative, target_is_directory=True)


@dataclass
class VariantTraining:
    """A detector training with some of its model's fields replaced."""

    training: Any
    model: dict[str, Any] = field(default_factory=dict)


def train_variant(job: VariantTraining) -> Path:
    from aed_models.detectors import DETECTORS
    from aed_models.train.detector import train_detector

    t = job.training
    model = DETECTORS.preset(t.detector, t.profile, **job.model) if job.model else None
    return train_detector(t, model)


def experiment_stages(protocol: Any, experiment: DetectorExperiment) -> list[Any]:
    """The stages an experiment needs once on `protocol`'s task, before its variants, in the
    main run's data folder: the novel environments' sub-optimal demonstrations, or their
    demonstrations and labelled episodes through another camera (the same seeds as the main
    run's, so the same episodes seen from elsewhere)."""
    from aed_eval.collect import run_collection
    from aed_eval.demo import Stage, collection

    layout, stages = RunLayout(protocol.runs), []
    if any(v.suboptimal_demos for v in experiment.variants):
        demos = collection(
            protocol,
            "novel",
            num_demos=0,
            num_suboptimal_demos=protocol.num_demos,
            num_successes=0,
            num_failures=0,
            num_envs=protocol.novel_envs,
            out=layout.data(protocol.task, SUBOPTIMAL),
        )
        name = f"{experiment.name}: collect sub-optimal demonstrations"
        stages.append(Stage(name, [(run_collection, demos)]))
    for camera in sorted({v.camera for v in experiment.variants} - {"front"}):
        seen = collection(
            protocol,
            "novel",
            num_demos=protocol.num_demos,
            num_successes=protocol.labelled,
            num_failures=protocol.labelled,
            num_envs=protocol.novel_envs,
            cameras=(camera,),
            out=layout.data(protocol.task, camera_data(camera)),
        )
        name = f"{experiment.name}: collect novel episodes through {camera}"
        stages.append(Stage(name, [(run_collection, seen)]))
    return stages


def variant_stages(protocol: Any, experiment: DetectorExperiment, variant: Variant) -> list[Any]:
    """The stages of one non-baseline variant on `protocol`'s task: link, then train the
    detectors and calibrate them (a detector variant) or roll the policies out again (a rollout
    variant), then evaluate."""
    from aed_eval.calibrate import calibrate_detectors
    from aed_eval.demo import Stage, calibrations, detector_trainings, evaluations, rollouts
    from aed_eval.evaluate import evaluate_policy
    from aed_eval.rollout import run_rollouts

    root = variant_root(protocol.runs, experiment.name, variant)
    c = dataclasses.replace(
        protocol, runs=root, policies=experiment.policies, detectors=experiment.detectors
    )
    prefix = f"{experiment.name} / {variant.name}"
    shared = ROLLOUT_SHARED if variant.rolls_out else DETECTOR_SHARED
    link = LinkConfig(protocol.runs, root, c.task, shared)
    stages = [Stage(f"{prefix}: link", [(link_shared, link)])]
    given: dict[str, Any] = {}
    scored: dict[str, Any] = {}
    if variant.suboptimal_demos:
        given = {
            "num_suboptimal_demos": variant.num_suboptimal(c.num_demos),
            "suboptimal_demos": RunLayout(protocol.runs).data(c.task, SUBOPTIMAL),
        }
    if variant.camera != "front":
        seen = RunLayout(protocol.runs).data(c.task, camera_data(variant.camera))
        given |= {"camera": variant.camera, "demos": seen}
        scored = {"labelled": seen}
    if variant.rolls_out:
        novel = [dataclasses.replace(r, **given) for r in rollouts(c) if r.split == "novel"]
        stages.append(Stage(f"{prefix}: roll out policies", [(run_rollouts, r) for r in novel]))
    else:
        trainings = [
            VariantTraining(dataclasses.replace(t, **variant.training), dict(variant.model))
            for t in detector_trainings(c)
        ]
        stages += [
            Stage(f"{prefix}: train detectors", [(train_variant, t) for t in trainings]),
            Stage(f"{prefix}: calibrate", [(calibrate_detectors, x) for x in calibrations(c)]),
        ]
    evaluated = [dataclasses.replace(e, **given, **scored) for e in evaluations(c)]
    stages.append(Stage(f"{prefix}: evaluate", [(evaluate_policy, x) for x in evaluated]))
    return stages


def _cells(results: dict[str, Any], detectors: Sequence[str], ending: str) -> dict[str, Any]:
    """Each detector's rollout-level AUROC and AUPRC with intervals, under one ending."""
    keys = ("auroc", "auroc_interval", "auprc", "auprc_interval")
    return {d: {k: results["detectors"][d][ending][k] for k in keys} for d in detectors}


def _labelled_cells(results: dict[str, Any], detectors: Sequence[str]) -> dict[str, Any]:
    """Each detector's time-matched AUROC (with interval) on the labelled novel episodes, for
    the detectors the evaluation scored there."""
    keys = ("time_matched_auroc", "time_matched_auroc_interval")
    scored = results["detectors"]
    return {
        d: {k: scored[d]["labelled"][k] for k in keys} for d in detectors if "labelled" in scored[d]
    }


def variants_record(
    runs: Path, experiment: DetectorExperiment, task: str, policy: str
) -> dict[str, Any]:
    """Every variant's rollout-level AUROC and AUPRC (with intervals) of one (task, policy),
    read from the variants' evaluations: under the default ending, and under the paper's, the
    metric of the paper's numbers (`aed_eval.paper`) the record carries where it gives them;
    and its time-matched AUROC on the labelled novel episodes, where they were scored."""
    rows = {}
    for variant in experiment.variants:
        path = RunLayout(variant_root(runs, experiment.name, variant)).evaluation(task, policy)
        results = json.loads((path / "results.json").read_text())
        rows[variant.name] = {
            "evaluation": str(path),
            "policy_sha256": results["policy_sha256"],
            "outcomes": results["rollouts"]["outcomes"][results["ending"]],
            "detectors": _cells(results, experiment.detectors, results["ending"]),
        }
        if "success" in results["endings"]:  # the paper's ending: its numbers' metric
            rows[variant.name]["paper_ending"] = _cells(results, experiment.detectors, "success")
        labelled = _labelled_cells(results, experiment.detectors)
        if labelled:
            rows[variant.name]["labelled"] = labelled
    shas = {row["policy_sha256"] for row in rows.values()}
    if len(shas) != 1:
        raise ValueError(f"{experiment.name} {task}/{policy}: variants scored different policies")
    return {
        "kind": "detector_variants",
        "experiment": experiment.name,
        "title": experiment.title,
        "task": task,
        "policy": policy,
        "detectors": list(experiment.detectors),
        "spread": experiment.spread,
        "variants": rows,
        "paper": paper.variant_numbers(experiment.name, task, policy),
    }

"""Results records: rendered from their JSON alone, checked against what is committed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from aed_eval.cli import main as aed_main
from aed_eval.results import load_record, records_under, stale_markdown, write_result
from aed_eval.results.timing import timing_record

REPO = Path(__file__).resolve().parents[1]
DETECTORS = ("probe", "lstm_ed")


def test_every_committed_table_is_what_its_json_renders_to():
    """Nothing under results/ is edited by hand: re-rendering every record reproduces it."""
    assert len(records_under(REPO / "results")) >= 2
    assert stale_markdown(REPO / "results") == []


def write_evaluation(folder: Path) -> Path:
    """A minimal `aed evaluate` folder: two rollouts (env 1 failed, env 0 succeeded), one
    labelled failure with its onset at frame 3, thresholds at policy@0.1."""
    folder.mkdir(parents=True)
    rollouts = [
        {"env_index": 1, "seed": 5, "success": False, "onset_frame": None},
        {"env_index": 0, "seed": 9, "success": True, "onset_frame": None},
    ]
    labelled = [{"env_index": 0, "seed": 2, "success": False, "onset_frame": 3}]
    scores = {
        "rollouts": {
            "episodes": rollouts,
            "scores": {"probe": [[0.1, 0.7, 0.9], [0.1, 0.2, 0.3]], "lstm_ed": [[0.0] * 3] * 2},
        },
        "labelled": {
            "episodes": labelled,
            "scores": {"probe": [[0.0, 0.1, 0.2, 0.4, 0.8, 0.9]], "lstm_ed": [[0.0] * 6]},
        },
    }
    delays = {"counts": {"early": 0, "on_time": 1, "late": 0, "missed": 0}, "median_delay": 1.0}
    results = {
        "task": "PressButton",
        "policy": "scan",
        "policy_sha256": "ab" * 32,
        "ending": "horizon",
        "detectors": {
            d: {
                "horizon": {"calibrated": {"policy@0.1": {"threshold": 0.5}}},
                "labelled": {"delays": {"policy@0.1": delays}},
            }
            for d in DETECTORS
        },
    }
    (folder / "results.json").write_text(json.dumps(results))
    (folder / "scores.json").write_text(json.dumps(scores))
    return folder


def test_timing_record_shows_the_first_episode_of_each_kind_and_its_alarms(tmp_path):
    record = timing_record(write_evaluation(tmp_path / "eval"))
    titles = [p["title"] for p in record["panels"]]
    assert titles == ["successful rollout", "failed rollout", "labelled failure"]
    success, failure, labelled = record["panels"]
    assert success["episode"]["env_index"] == 0 and failure["episode"]["env_index"] == 1
    assert failure["first_alarm"] == {"probe": 1, "lstm_ed": None}
    assert success["first_alarm"]["probe"] is None and labelled["first_alarm"]["probe"] == 4
    assert record["thresholds"] == {"probe": 0.5, "lstm_ed": 0.5}

    written = write_result(tmp_path / "out" / "PressButton_scan.json", record)
    assert [p.suffix for p in written] == [".json", ".md", ".png"]
    table = written[1].read_text()
    assert "| probe | 0.5 | none | 1 | 4 (+1) | 0 / 1 / 0 / 0 | 1 |" in table
    assert stale_markdown(tmp_path / "out") == []
    written[1].write_text(table.replace("4 (+1)", "3 (+0)"))  # edited by hand
    assert stale_markdown(tmp_path / "out") == [
        f"{written[1]}: differs from what {written[0]} renders to"
    ]


def test_timing_record_names_a_missing_evaluation_or_threshold(tmp_path):
    with pytest.raises(FileNotFoundError, match="results.json: missing; run `aed evaluate`"):
        timing_record(tmp_path)
    with pytest.raises(ValueError, match=r"probe has no policy@0.2 threshold"):
        timing_record(write_evaluation(tmp_path / "eval"), alpha=0.2)


def test_timing_record_falls_back_to_expert_thresholds_without_policy_successes(tmp_path):
    """A policy with no success among its calibration rollouts has only `expert@` thresholds:
    the curves are drawn against those, and the record says so."""
    folder = write_evaluation(tmp_path / "eval")
    results = json.loads((folder / "results.json").read_text())
    for d in DETECTORS:
        results["detectors"][d]["horizon"]["calibrated"] = {"expert@0.1": {"threshold": 0.25}}
    missed = {"counts": {"early": 0, "on_time": 0, "late": 0, "missed": 1}, "median_delay": None}
    results["detectors"]["lstm_ed"]["labelled"]["delays"] = {"expert@0.1": missed}
    (folder / "results.json").write_text(json.dumps(results))
    record = timing_record(folder)
    assert record["calibration"] == "expert@0.1"
    assert record["thresholds"] == {"probe": 0.25, "lstm_ed": 0.25}
    assert record["panels"][1]["first_alarm"]["probe"] == 1
    table = write_result(tmp_path / "out" / "case.json", record)[1].read_text()
    assert "at the expert@0.1 threshold" in table
    assert "| lstm_ed | 0.25 | none | none | none | 0 / 0 / 0 / 1 | - |" in table  # all missed
    with pytest.raises(ValueError, match=r"probe has no expert@0.1 threshold"):
        timing_record(write_evaluation(tmp_path / "policy_only"), calibration="expert")


def test_a_corrupt_or_foreign_record_is_named(tmp_path):
    path = tmp_path / "r.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match="r.json: not a readable JSON results record"):
        load_record(path)
    path.write_text(json.dumps({"kind": "nothing_known"}))
    with pytest.raises(ValueError, match="unknown results kind 'nothing_known'"):
        load_record(path)
    path.write_text(json.dumps([1, 2]))
    with pytest.raises(ValueError, match="not a results record"):
        load_record(path)
    with pytest.raises(ValueError, match="record kind None"):
        write_result(tmp_path / "new.json", {"rows": []})
    assert not (tmp_path / "new.json").exists()


def test_results_command_rerenders_and_checks(tmp_path, capsys):
    record = timing_record(write_evaluation(tmp_path / "eval"))
    json_path, md, _ = write_result(tmp_path / "out" / "case.json", record)
    md.unlink()
    assert aed_main(["results", "--roots", str(tmp_path / "out"), "--check"]) == 1
    assert f"{md}: missing" in capsys.readouterr().out
    assert aed_main(["results", "--roots", str(tmp_path / "out")]) == 0
    assert md.exists() and aed_main(["results", "--roots", str(tmp_path / "out"), "--check"]) == 0
    # plots are compared only when asked: their bytes are matplotlib's
    png = json_path.with_suffix(".png")
    png.write_bytes(png.read_bytes() + b"\0")
    assert aed_main(["results", "--roots", str(tmp_path / "out"), "--check"]) == 0
    capsys.readouterr()
    check_figures = ["results", "--roots", str(tmp_path / "out"), "--check", "--figures"]
    assert aed_main(check_figures) == 1
    assert f"{png}: differs from what {json_path} renders to" in capsys.readouterr().out
    assert aed_main(["results", "--roots", str(tmp_path / "out")]) == 0
    assert aed_main(check_figures) == 0
    assert "every table and plot as rendered" in capsys.readouterr().out


def test_policy_table_keeps_the_rows_of_tasks_measured_elsewhere(tmp_path, monkeypatch):
    """A call that measures Pick & Place keeps Press Button's rows and their command."""
    from tests.helpers import load_script

    script = load_script("policy_table")
    base = {"train_envs": 23, "action_chunk": 1, "epochs": 100, "train_seconds": 60.0}
    base |= {"pos_mse_first": 0.8, "pos_mse_last": 0.3, "rollouts": 10, "successes": 2}
    base |= {"success_rate": 0.2, "interval": [0.0, 0.5], "paper_success": None}
    older = [{**base, "task": "PressButton", "policy": p} for p in ("naive_dc", "scan")]
    out = tmp_path / "policies.json"
    write_result(out, {"kind": "policy_table", "command": "python old.py", "records": older})
    measured = {"task": "PickPlace", "policy": "scan", "action_chunk": 10, "own_pos_mse_last": 0.2}
    measured |= {"demos_per_env": 5, "successes_per_env": [10], "localizer_seconds": 600.0}
    monkeypatch.setattr(script, "row", lambda layout, t, p: {**base, **measured})
    monkeypatch.setattr("sys.argv", ["scripts/policy_table.py", "--tasks", "PickPlace"])
    script.main(script.Config(runs=tmp_path, tasks=("PickPlace",), policies=("scan",), out=out))
    rows = load_record(out)["records"]
    assert [(r["task"], r["policy"]) for r in rows] == [
        ("PressButton", "naive_dc"),
        ("PressButton", "scan"),
        ("PickPlace", "scan"),
    ]
    table = out.with_suffix(".md").read_text()
    assert "`python old.py` (PressButton)" in table
    older_row = "| PressButton | scan | 23 envs | 100 epochs, chunks of 1, 1.0 min | 0.80 -> 0.30 |"
    assert older_row in table
    assert "| PickPlace | scan | 23 x (5 + 10) | 100 epochs, chunks of 10, 1.0 min " in table
    assert "(task's localizer 10 min) | 0.80 -> 0.30 (0.20) |" in table
    assert "`python scripts/policy_table.py --tasks PickPlace` (PickPlace)" in table
    (tmp_path / "other.json").write_text(json.dumps({"kind": "lever_table", "records": []}))
    with pytest.raises(ValueError, match="not a policy table"):
        script.kept_rows(tmp_path / "other.json", ("PickPlace",))


def variant_cells(auprc: float) -> dict:
    cell = {"auroc": 0.6, "auroc_interval": [0.5, 0.7], "auprc": auprc}
    return {d: {**cell, "auprc_interval": [auprc - 0.1, auprc + 0.1]} for d in DETECTORS}


def test_a_variant_table_stands_beside_the_papers_numbers_under_both_endings(tmp_path):
    """Demonstration quality, DCT: here (default ending, the paper's ending) / the paper's AUPRC
    for each variant and detector; a variant evaluated without the paper's ending says n/a."""
    from aed_eval import paper

    theirs = paper.variant_numbers("demo_quality", "PressButton", "dct")
    assert theirs["metric"] == "auprc"
    assert list(theirs["variants"]) == ["all optimal", "2 sub-optimal", "all sub-optimal"]
    variants = {
        name: {
            "outcomes": {"successes": 3, "failures": 7},
            "detectors": variant_cells(0.4),
            "paper_ending": variant_cells(0.55),
        }
        for name in theirs["variants"]
    }
    del variants["all sub-optimal"]["paper_ending"]
    record = {
        "kind": "detector_variants",
        "experiment": "demo_quality",
        "title": "Demonstration quality",
        "task": "PressButton",
        "policy": "dct",
        "detectors": list(DETECTORS),
        "spread": False,
        "variants": variants,
        "paper": theirs,
    }
    table = write_result(tmp_path / "dq.json", record)[1].read_text()
    assert "| AUPRC | all optimal: here | here, paper's ending | paper | 2 sub-optimal:" in table
    assert "| policy success rate | 30.0% | | 80.56 +- 11.65% | 30.0% | | 78.61 +- 14.02%" in table
    assert (
        "| probe | 0.400 | 0.550 | 0.7474 | 0.400 | 0.550 | 0.7530 | 0.400 | n/a | 0.7588 |"
        in table
    )
    assert stale_markdown(tmp_path) == []


def test_a_variant_table_shows_the_labelled_episodes_time_matched_auroc(tmp_path):
    """Beside the rollout metrics, each variant's time-matched AUROC on the labelled novel
    episodes; a variant scored without them says n/a and the spread is over those that have it."""

    def labelled(value: float) -> dict:
        return {"probe": {"time_matched_auroc": value, "time_matched_auroc_interval": [0.1, 0.9]}}

    outcomes = {"successes": 5, "failures": 5}
    record = {
        "kind": "detector_variants",
        "experiment": "seeds",
        "title": "Stability",
        "task": "PickPlace",
        "policy": "scan",
        "detectors": ["probe"],
        "spread": True,
        "variants": {
            "seed 0": {
                "outcomes": outcomes,
                "detectors": variant_cells(0.7),
                "labelled": labelled(0.8),
            },
            "seed 1": {
                "outcomes": outcomes,
                "detectors": variant_cells(0.7),
                "labelled": labelled(0.6),
            },
            "seed 2": {"outcomes": outcomes, "detectors": variant_cells(0.7)},
        },
        "paper": None,
    }
    table = write_result(tmp_path / "seeds.json", record)[1].read_text()
    assert "| time-matched AUROC [95%] | seed 0 | seed 1 | seed 2 | mean +- std |" in table
    assert "| probe | 0.800 [0.100, 0.900] | 0.600 [0.100, 0.900] | n/a | 0.700 +- 0.141 |" in table
    assert "| probe | 0.600 [0.500, 0.700] | 0.600 [0.500, 0.700] | 0.600 [0.500, 0.700] |" in table
    for variant in record["variants"].values():
        variant.pop("labelled", None)
    assert "time-matched" not in write_result(tmp_path / "none.json", record)[1].read_text()


def test_the_paper_gives_numbers_only_for_what_it_ran():
    from aed_eval import paper
    from aed_tasks import PAPER_TASK_ORDER

    assert paper.variant_numbers("viewpoint", "PressButton", "dct")["metric"] == "auroc"
    assert paper.variant_numbers("viewpoint", "PressButton", "scan") is None  # DCT only
    assert paper.variant_numbers("demo_quality", "PickPlace", "dct") is None
    assert paper.variant_numbers("rollout_augmentation", "PickPlace", "scan") is None  # a figure
    assert paper.correction_numbers("PressButton", "scan") is None
    assert list(paper.POLICY_SUCCESS) == list(PAPER_TASK_ORDER)
    assert all(set(rates) == {"naive_dc", "dct", "scan"} for rates in paper.POLICY_SUCCESS.values())


def test_the_correction_table_shows_the_papers_rates_beside_ours(tmp_path):
    from aed_eval import paper

    quiet = {"alarmed": 0, "alarmed_on_success": 0, "only_without": 0, "only_with": 0}
    detectors = {d: {"successes": 5, **quiet, "quiet_replays_changed": 0} for d in DETECTORS}
    detectors["svdd_ed"] = detectors["probe"]
    record = {
        "kind": "error_correction",
        "task": "PressButton",
        "policy": "dct",
        "threshold": 0.9,
        "horizon": 200,
        "rollouts": 10,
        "successes_without": 5,
        "detectors": detectors,
        "paper": paper.correction_numbers("PressButton", "dct"),
    }
    table = write_result(tmp_path / "correction.json", record)[1].read_text()
    assert "| none (the stored rollouts) | 50.0% " in table and " 80.56 +- 11.65% |" in table
    assert table.count("82.22 +- 10.17% |") == 1 and "| svdd_ed |" in table
    assert [line for line in table.splitlines() if line.startswith("| svdd_ed")][0].endswith(
        "| not run |"
    )

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

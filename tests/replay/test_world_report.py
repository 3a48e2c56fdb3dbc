"""World report: per-task numbers from the stage artefacts, calibration episodes excluded."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from r2s_eval.stages import world_report
from r2s_eval.utils.io import write_parquet

CFG = json.dumps({"stats.n_boot": 400, "stats.ci_level": 0.95, "seed": 3})


def _artefacts(tmp_path):
    attempts = [{"task": "a", "attempt": i, "success": i != 3, "length": 70, "wall_s": 1.0} for i in range(10)]
    attempts += [{"task": "b", "attempt": i, "success": True, "length": 70, "wall_s": 2.0} for i in range(4)]
    write_parquet(tmp_path / "truth.parquet", pd.DataFrame({"episode_index": [0]}), metadata={"attempts": attempts})
    errors = pd.DataFrame([
        {"episode_index": e, "task": "a", "object": o, "error_xy_mm": 2.0 + e, "error_yaw_deg": 0.0 if o == "cup" else 3.0,
         "yaw_symmetry": 0 if o == "cup" else 4}
        for e in range(5) for o in ("cup", "block")
    ] + [{"episode_index": 9, "task": "b", "object": "ball", "error_xy_mm": 12.0, "error_yaw_deg": 0.0, "yaw_symmetry": 0}])
    errors.to_parquet(tmp_path / "errors.parquet")
    replay = pd.DataFrame([
        {"episode_index": e, "task": "a", "success": True, "attempts": 1 + (e == 2), "calibration": e == 0, "wall_s": 0.5}
        for e in range(5)
    ] + [{"episode_index": 9, "task": "b", "success": False, "attempts": 8, "calibration": False, "wall_s": 3.0}])
    replay.to_parquet(tmp_path / "replay.parquet")


def test_report_numbers_and_targets(tmp_path, capsys):
    _artefacts(tmp_path)
    out = tmp_path / "report.json"
    world_report.main(world_report.parser().parse_args([
        "--cfg", CFG, "--truth", str(tmp_path / "truth.parquet"), "--errors", str(tmp_path / "errors.parquet"),
        "--replay", str(tmp_path / "replay.parquet"), "--out", str(out)]))
    report = json.loads(out.read_text())
    a, b = report["tasks"]["a"], report["tasks"]["b"]
    assert a["teleop"]["success_rate"] == pytest.approx(0.9) and a["teleop"]["s_per_attempt"] == 1.0
    assert a["init_error"]["xy_mm_median"] == pytest.approx(4.0)
    # Yaw is summarised over the observable-yaw object only (the block), not the symmetric cup.
    assert a["init_error"]["yaw_deg_median"] == pytest.approx(3.0)
    assert a["init_error"]["objects"]["cup"]["yaw_deg_median"] is None
    # Replay: the calibration episode (0) is not test data.
    assert a["replay"]["episodes"] == 4 and a["replay"]["attempts_histogram"] == {"1": 3, "2": 1}
    # First attempt 3 of 4 (Wilson [0.301, 0.954]), all 4 after retries (Wilson [0.510, 1]).
    assert a["replay"]["first_attempt_successes"] == 3 and a["replay"]["first_attempt_rate"] == 0.75
    assert a["replay"]["first_attempt_ci"] == pytest.approx([0.3006, 0.9544], abs=1e-4)
    assert a["replay"]["success_ci"] == pytest.approx([0.5101, 1.0], abs=1e-4)
    assert a["meets_targets"] is True
    assert b["replay"]["success_rate"] == 0.0 and b["meets_targets"] is False
    printed = capsys.readouterr().out
    assert "block" in printed and " NO" in printed


def test_missing_attempt_log_is_named(tmp_path):
    _artefacts(tmp_path)
    write_parquet(tmp_path / "truth.parquet", pd.DataFrame({"episode_index": [0]}))
    with pytest.raises(ValueError, match="truth.parquet: no teleop attempt log"):
        world_report.main(world_report.parser().parse_args([
            "--cfg", CFG, "--truth", str(tmp_path / "truth.parquet"), "--errors", str(tmp_path / "errors.parquet"),
            "--replay", str(tmp_path / "replay.parquet")]))


def test_real_sim_gap_per_cell_and_over_cells(tmp_path, capsys):
    _artefacts(tmp_path)
    # Real (reference) and sim outcomes: policy p on task a, 1/6 real and 3/6 sim; q on a 6/6 on both.
    pd.DataFrame([{"policy": "p", "task": "a", "trials": 6, "successes": 1},
                  {"policy": "q", "task": "a", "trials": 6, "successes": 6}]).to_parquet(tmp_path / "reference.parquet")
    rollouts = []
    for policy, wins in (("p", 3), ("q", 6)):
        folder = tmp_path / "sim" / policy
        folder.mkdir(parents=True)
        pd.DataFrame({"episode_id": [f"{policy}{k}" for k in range(6)], "policy": policy, "arm": "sim", "task": "a",
                      "init_id": range(6), "seed": range(6), "success": [k < wins for k in range(6)],
                      "length": 50, "instruction": "x", "video_path": "v", "trajectory_path": "t"}
                     ).to_parquet(folder / "episodes.parquet")
        rollouts.append(str(folder))
    out = tmp_path / "report.json"
    world_report.main(world_report.parser().parse_args([
        "--cfg", CFG, "--truth", str(tmp_path / "truth.parquet"), "--errors", str(tmp_path / "errors.parquet"),
        "--replay", str(tmp_path / "replay.parquet"), "--reference", str(tmp_path / "reference.parquet"),
        "--rollouts", *rollouts, "--out", str(out)]))
    report = json.loads(out.read_text())
    cells = {c["policy"]: c for c in report["tasks"]["a"]["realsim_gap"]}
    # Newcombe's hybrid score interval of 3/6 - 1/6, by hand from the two Wilson intervals.
    assert cells["p"]["gap_pp"] == pytest.approx(100 / 3)
    assert cells["p"]["gap_ci_pp"] == pytest.approx([-17.17, 67.43], abs=0.01)
    assert cells["q"]["gap_pp"] == 0.0 and cells["q"]["gap_ci_pp"] == pytest.approx([-39.03, 39.03], abs=0.01)
    assert report["tasks"]["b"]["realsim_gap"] == []
    summary = report["realsim_gap"]
    assert summary["cells"] == 2 and summary["real_trials_per_cell"] == [6] and summary["sim_trials_per_cell"] == [6]
    assert summary["mean_abs_gap_pp"] == pytest.approx(50 / 3) and summary["max_abs_gap_pp"] == pytest.approx(100 / 3)
    lo, hi = summary["mean_abs_gap_ci_pp"]
    assert 0.0 <= lo < summary["mean_abs_gap_pp"] < hi <= 100.0
    # The all-success cell never varies in the bootstrap: the signed mean's interval comes from p's alone.
    slo, shi = summary["mean_gap_ci_pp"]
    assert slo < summary["mean_gap_pp"] < shi and shi - slo < 100.0
    printed = capsys.readouterr().out
    assert "real-sim gap over 2 policy-task cells" in printed and "+33 [-17, +67]" in printed

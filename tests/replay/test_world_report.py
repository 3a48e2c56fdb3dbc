"""World report: per-task numbers from the stage artefacts, calibration episodes excluded."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from r2s_eval.stages import world_report
from r2s_eval.utils.io import write_parquet


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
        "--truth", str(tmp_path / "truth.parquet"), "--errors", str(tmp_path / "errors.parquet"),
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
    assert a["meets_targets"] is True
    assert b["replay"]["success_rate"] == 0.0 and b["meets_targets"] is False
    printed = capsys.readouterr().out
    assert "block" in printed and " NO" in printed


def test_missing_attempt_log_is_named(tmp_path):
    _artefacts(tmp_path)
    write_parquet(tmp_path / "truth.parquet", pd.DataFrame({"episode_index": [0]}))
    with pytest.raises(ValueError, match="truth.parquet: no teleop attempt log"):
        world_report.main(world_report.parser().parse_args([
            "--truth", str(tmp_path / "truth.parquet"), "--errors", str(tmp_path / "errors.parquet"),
            "--replay", str(tmp_path / "replay.parquet")]))

"""Per-task offsets: the held-out calibration subset, the fit, and its use by the estimate."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from r2s_eval.calib import calibration_subset, fit_offsets


def _index(tasks_episodes):
    rows = [{"episode_index": i, "task": t} for t, eps in tasks_episodes.items() for i in eps]
    return pd.DataFrame(rows)


def test_calibration_subset_is_the_first_episodes_of_each_task():
    index = _index({"a": [0, 1, 2, 3], "b": [4, 5, 6]})
    subset = calibration_subset(index.sample(frac=1.0, random_state=0), 2)
    assert sorted(subset["episode_index"]) == [0, 1, 4, 5]
    assert calibration_subset(index, 0).empty


def test_calibration_subset_must_leave_test_episodes():
    with pytest.raises(ValueError, match="task 'b' has 2 episode"):
        calibration_subset(_index({"a": [0, 1, 2], "b": [3, 4]}), 2)


def test_fit_recovers_a_systematic_shift_and_yaw_modulo_symmetry():
    rng = np.random.default_rng(0)
    rows_est, rows_true = [], []
    shift = {"cup": (0.004, -0.012, 0.0), "block": (-0.003, 0.002, np.deg2rad(3.0))}
    symmetry = {"cup": 0, "block": 4}
    for ep in range(6):
        for obj in ("cup", "block"):
            x, y, yaw = rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-np.pi, np.pi)
            dx, dy, dyaw = shift[obj]
            noise = rng.normal(0, 0.0005, 2)
            rows_true.append({"episode_index": ep, "object": obj, "x_m": x, "y_m": y, "yaw_rad": yaw})
            # Block yaw estimated a quarter turn away as well: invisible for a 4-fold symmetric block.
            est_yaw = yaw - dyaw + (np.pi / 2 if obj == "block" and ep % 2 else 0.0)
            rows_est.append({"episode_index": ep, "task": "t", "object": obj, "x_m": x - dx + noise[0],
                             "y_m": y - dy + noise[1], "yaw_rad": est_yaw, "yaw_symmetry": symmetry[obj]})
    offsets = fit_offsets(pd.DataFrame(rows_est), pd.DataFrame(rows_true))
    for obj, (dx, dy, dyaw) in shift.items():
        got = offsets["t"][obj]
        assert got[0] == pytest.approx(dx, abs=5e-4) and got[1] == pytest.approx(dy, abs=5e-4)
        assert got[2] == pytest.approx(dyaw, abs=1e-6)


def test_fit_names_calibration_episodes_without_measurements():
    est = pd.DataFrame([{"episode_index": 7, "task": "t", "object": "cup", "x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0,
                         "yaw_symmetry": 0}])
    measured = pd.DataFrame(columns=["episode_index", "object", "x_m", "y_m", "yaw_rad"])
    with pytest.raises(ValueError, match=r"\(7, 'cup'\)"):
        fit_offsets(est, measured)


def test_calibrate_offsets_without_measured_poses_is_zero_and_not_fitted(monkeypatch):
    from r2s_eval.calib import episodes

    monkeypatch.setattr(episodes, "estimate_episodes", lambda *a, **k: pytest.fail("nothing to estimate"))
    result = episodes.calibrate_offsets(_index({"a": [0, 1, 2]}), "frames", {}, {}, None, per_task=1)
    assert result == {"offsets": {}, "calibration_episodes": [0], "episodes_per_task": 1, "fitted": False,
                      "calibration_error": {}}


def test_calibrate_offsets_fits_the_calibration_episodes_and_scores_before_and_after(monkeypatch, tmp_path):
    from r2s_eval.calib import episodes

    index = _index({"t": [0, 1, 2, 3]})
    measured = pd.DataFrame({"episode_index": [0, 1, 2, 3], "object": "cup", "x_m": [0.1, 0.2, 9.0, 9.0],
                             "y_m": 0.0, "yaw_rad": 0.0})
    measured.to_parquet(tmp_path / "measured.parquet")

    def estimate(subset, frames_dir, calib, world, offsets=None, desc="init", cameras=None):
        assert offsets is None and sorted(subset["episode_index"]) == [0, 1]  # the calibration episodes only
        return pd.DataFrame({"episode_index": [0, 1], "task": "t", "object": "cup", "x_m": [0.09, 0.19],
                             "y_m": 0.0, "yaw_rad": 0.0, "yaw_symmetry": 0})

    monkeypatch.setattr(episodes, "estimate_episodes", estimate)
    result = episodes.calibrate_offsets(index, "frames", {}, {}, str(tmp_path / "measured.parquet"), per_task=2)
    assert result["fitted"] and result["calibration_episodes"] == [0, 1]
    assert result["offsets"]["t"]["cup"] == pytest.approx([0.01, 0.0, 0.0])
    error = result["calibration_error"]["t"]["cup"]
    assert error["xy_mm_median_before"] == pytest.approx(10.0) and error["xy_mm_median_after"] == pytest.approx(0.0)


def test_score_estimates_leaves_out_calibration_episodes_and_summarises_per_object():
    from r2s_eval.calib import score_estimates
    from r2s_eval.errors import DataError

    estimates = pd.DataFrame({"episode_index": [0, 1, 2], "task": "t", "object": "cup", "x_m": [0.0, 0.003, 0.0],
                              "y_m": [0.0, 0.004, 0.0], "yaw_rad": [0.0, 0.1, 0.2], "yaw_symmetry": 0,
                              "calibration": [True, False, False]})
    truth = pd.DataFrame({"episode_index": [1, 2], "task": "t", "object": "cup", "x_m": 0.0, "y_m": 0.0,
                          "yaw_rad": 3.0, "yaw_symmetry": 0})
    errors, summary = score_estimates(estimates, truth)
    assert errors["episode_index"].tolist() == [1, 2] and "calibration" not in errors
    assert errors["error_xy_mm"].tolist() == pytest.approx([5.0, 0.0])
    assert errors["error_yaw_deg"].tolist() == [0.0, 0.0]  # a symmetric object's yaw is not scored
    cup = summary["tasks"]["t"]["cup"]
    assert cup["episodes"] == 2 and cup["xy_mm_median"] == pytest.approx(2.5) and cup["yaw_symmetry"] == 0
    with pytest.raises(DataError, match=r"no true pose for \(episode, object\) \[\(2, 'cup'\)\]"):
        score_estimates(estimates, truth[truth["episode_index"] == 1])

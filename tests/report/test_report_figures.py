"""Each figure has the expected panels and is written as a non-empty PDF and PNG."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.image import imread

from r2s_eval.report import (
    case_study_figure,
    convergence_figure,
    hardware_effort_figure,
    judge_averaged_scores,
    operator_hours,
    ranking_figure,
    sample_frames,
    save_figure,
    win_rate_figure,
    win_rate_matrix,
)
from r2s_eval.rollout.mp4 import write_video

from .conftest import figure_opts

SECONDS = {"execution": 60, "reset": 45, "monitoring": 15, "recording": 10}


def saved(fig, tmp_path, name="fig"):
    pdf, png = tmp_path / f"{name}.pdf", tmp_path / f"{name}.png"
    save_figure(fig, pdf, png, dpi=50)
    assert pdf.read_bytes().startswith(b"%PDF") and pdf.stat().st_size > 1000
    image = imread(png)
    assert image.shape[0] > 50 and image.shape[1] > 50
    assert image[..., :3].std() > 0  # not a blank canvas
    return pdf, png


def visible_axes(fig):
    return [ax for ax in fig.axes if ax.get_visible()]


def test_win_rate_figure(tmp_path, verdicts):
    fig = win_rate_figure(win_rate_matrix(verdicts), "kinematic", figure_opts("win_rate_matrix", annotate=True))
    heatmap, colorbar = fig.axes
    assert heatmap.get_title() == "Win rate, judge kinematic"
    assert [t.get_text() for t in heatmap.get_yticklabels()] == ["a", "b", "c"]
    assert sorted(t.get_text() for t in heatmap.texts) == sorted(["100", "50", "0", "100", "50", "0"])
    assert colorbar.get_ylabel() == "row wins (%)"
    saved(fig, tmp_path)


def test_convergence_figure_one_panel_per_judge(tmp_path, make_fit):
    fit = make_fit({10: {"a": (60, 50, 70), "b": (40, 30, 50)}, 20: {"a": (65, 58, 72), "b": (35, 28, 42)}})
    fig = convergence_figure({"j1": fit, "j2": fit, "j3": fit, "j4": fit}, figure_opts("bt_convergence", columns=3))
    panels = visible_axes(fig)
    assert [ax.get_title() for ax in panels] == ["j1", "j2", "j3", "j4"]
    assert len(fig.axes) == 6  # a 2 x 3 grid, the last two hidden
    assert len(panels[0].lines) == 2 and len(panels[0].collections) == 2  # a curve and a band per policy
    np.testing.assert_allclose(panels[0].lines[0].get_ydata(), [60, 65])
    saved(fig, tmp_path)


def test_ranking_figure_beside_reference(tmp_path, make_fit):
    fits = {"j1": make_fit({10: {"a": (70, 60, 80), "b": (30, 20, 40)}}),
            "j2": make_fit({10: {"a": (50, 40, 60), "b": (50, 40, 60)}})}
    fig = ranking_figure(judge_averaged_scores(fits), {"a": 0.2, "b": 0.6}, figure_opts("overall_ranking"))
    scores, reference = fig.axes
    assert scores.get_title() == "Preference (2 judges)" and reference.get_title() == "Reference"
    assert [t.get_text() for t in scores.get_yticklabels()] == ["a", "b"]  # best reference on top
    np.testing.assert_allclose([p.get_width() for p in scores.patches], [60, 40])
    np.testing.assert_allclose([p.get_width() for p in reference.patches], [20, 60])
    assert "-1.00" in fig.get_suptitle()  # the judges reverse the reference order
    with pytest.raises(ValueError, match=r"no reference success rate for policies \['b'\]"):
        ranking_figure(judge_averaged_scores(fits), {"a": 0.2}, figure_opts("overall_ranking"))
    saved(fig, tmp_path)


def test_operator_hours_grow_with_tasks_and_trials():
    hours = operator_hours(SECONDS, n_policies=3, tasks=2, trials_per_task=np.array([0, 10]))
    assert sum(h[1] for h in hours.values()) == pytest.approx(3 * 2 * 10 * 130 / 3600)
    assert hours["reset"][1] == pytest.approx(60 * 45 / 3600) and all(h[0] == 0 for h in hours.values())
    with pytest.raises(ValueError, match=r"lacks components \['recording'\]"):
        operator_hours({k: v for k, v in SECONDS.items() if k != "recording"}, 1, 1, 1)


def test_hardware_effort_figure(tmp_path):
    fig = hardware_effort_figure(SECONDS, 3, (1, 6), figure_opts("hardware_effort", tasks=[1, 7], max_trials_per_task=20))
    left, right = fig.axes
    assert len(left.collections) == 4  # one stacked area per component
    labels = [line.get_label() for line in right.lines]
    assert labels == ["1 task", "7 tasks", "r2s-eval"]
    np.testing.assert_allclose(right.lines[-1].get_ydata(), 0.0)  # no repeated hardware time
    np.testing.assert_allclose(right.lines[1].get_ydata()[-1], 3 * 7 * 20 * 130 / 3600)
    assert any("this run: 0.7 h" in t.get_text() for t in left.texts)  # 3 policies x 6 trials x 130 s
    saved(fig, tmp_path)


def test_case_study_from_rollout_videos(tmp_path):
    rows = []
    for label, n_frames, shade in (("preferred\na (success)", 20, 40), ("other\nb (success)", 12, 200)):
        frames = [np.full((32, 32, 3), shade, dtype=np.uint8) for _ in range(n_frames)]
        for k, frame in enumerate(frames):
            frame[:, : k + 1] = 255 - shade  # a bar that grows, so frames differ
        write_video(tmp_path / f"{n_frames}.mp4", frames, fps=10)
        picked, times = sample_frames(tmp_path / f"{n_frames}.mp4", 4)
        assert len(picked) == 4 and picked[0].shape == (32, 32, 3)
        assert times[0] == 0.0 and times[-1] == pytest.approx((n_frames - 1) / 10)
        rows.append((label, picked, times))
    fig = case_study_figure(rows, "Judge kinematic, task cup_on_plate", "smoother approach " * 20, figure_opts("case_study", wrap_chars=60))
    assert len(visible_axes(fig)) == 8  # two rollouts x four frames
    assert fig.axes[0].get_ylabel() == "preferred\na (success)" and fig.axes[4].get_ylabel() == "other\nb (success)"
    assert fig.axes[3].get_xlabel() == "t = 1.9 s"
    assert "smoother approach" in fig.get_suptitle()
    saved(fig, tmp_path)


def test_sample_frames_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.mp4"):
        sample_frames(tmp_path / "missing.mp4", 3)
    with pytest.raises(ValueError, match="at least one frame"):
        sample_frames(tmp_path / "missing.mp4", 0)


def test_pdf_is_reproducible(tmp_path, make_fit):
    fit = make_fit({10: {"a": (60, 50, 70), "b": (40, 30, 50)}})
    a, _ = saved(convergence_figure({"j": fit}, figure_opts("bt_convergence")), tmp_path, "a")
    b, _ = saved(convergence_figure({"j": fit}, figure_opts("bt_convergence")), tmp_path, "b")
    assert a.read_bytes() == b.read_bytes()


def test_figures_name_the_interval_and_show_the_reference_interval(tmp_path, make_fit):
    fit = make_fit({10: {"a": (70, 60, 80), "b": (30, 20, 40)}})
    fit["interval"], fit["ci_level"] = "unit", 0.95
    assert convergence_figure({"j": fit}, figure_opts("bt_convergence")).get_suptitle() == "bands: 95% unit-bootstrap interval"
    fig = ranking_figure(judge_averaged_scores({"j": fit}), {"a": 0.2, "b": 0.6}, figure_opts("overall_ranking"),
                         reference_ci={"a": (0.1, 0.35), "b": (0.5, 0.7)})
    reference = fig.axes[1]
    assert reference.get_xlabel() == "real success (%, mean over tasks)"
    bars = [c for c in reference.containers if getattr(c, "errorbar", None) is not None]
    segments = bars[0].errorbar.lines[2][0].get_segments()
    np.testing.assert_allclose([[s[0][0], s[1][0]] for s in segments], [[10, 35], [50, 70]])
    saved(fig, tmp_path)

"""The fidelity report's table, text and figure from a cross-evaluation."""

from __future__ import annotations

import numpy as np
import pandas as pd
from PIL import Image

from r2s_eval.report import save_figure
from r2s_eval.report.fidelity_report import (ablation_figure, ablation_rows, ablation_table, fidelity_table, format_report,
                                      joint_report)
from r2s_eval.stats.fidelity import cross_evaluation

OPTS = {"decimals": 1, "width_in": 4.0, "height_in": 2.8, "font_size": 9, "dpi": 80}


def counts(rows):
    return pd.DataFrame(rows, columns=["policy", "task", "successes", "trials"])


def episodes(policy, successes, trials):
    return pd.DataFrame({"policy": policy, "success": [k < successes for k in range(trials)]})


def report():
    worlds = {"R_real": counts([("act", "cup_on_plate", 10, 18)]), "R_sim": counts([("act", "cup_on_plate", 8, 18)]),
              "S_sim": counts([("act", "cup_on_plate", 7, 18)]), "S_real": counts([("act", "cup_on_plate", 5, 18)])}
    ablation = ablation_rows({"joints": episodes("act", 7, 18), "all": episodes("act", 7, 18)},
                             episodes("act", 5, 18), level=0.95)
    joints = joint_report({"left": [0.01, -0.02]}, {"left": [0.011, -0.02]})
    return {"cross": cross_evaluation(worlds, 0.95, 100, 0), "joints": joints, "ablation": ablation, "seeds": []}


def test_table_has_every_world_and_both_parts():
    table = fidelity_table(report())
    assert r"\toprule" in table and r"$\pi^S$ real" in table
    row = next(line for line in table.splitlines() if line.startswith(r"cup\_on\_plate"))
    # 10, 8, 7, 5 of 18; calibration 8 - 10 of 18 = -11.1 pp, training 7 - 8 of 18 = -5.6 pp
    assert "55.6 & 44.4 & 38.9 & 27.8 & -11.1 [" in row and "& -5.6 [" in row
    assert r"calibration ($\pi^R$ sim $-$ $\pi^R$ real): mean $|$gap$|$ 11.1 pp" in table
    assert "R_sim" not in table  # every note is LaTeX


def test_text_names_the_joint_error_and_each_familys_cost():
    text = format_report(report())
    assert "largest error 0.057 deg" in text
    assert "ablation act without joints    :  38.9 %" in text and "cost +11.1 pp" in text


def test_joint_report_without_a_twin_has_no_truth():
    arms = joint_report({"left": [0.01]}, None)["arms"]
    assert arms["left"]["truth_deg"] is None and np.isclose(arms["left"]["estimated_deg"][0], np.rad2deg(0.01))
    assert joint_report(None, None) == {"estimated": False, "arms": {}}


def test_ablation_figure_is_drawn(tmp_path):
    r = report()
    fig = ablation_figure(r["ablation"], {"act": 7 / 18}, OPTS)
    save_figure(fig, tmp_path / "a.pdf", tmp_path / "a.png", dpi=80)
    with Image.open(tmp_path / "a.png") as image:
        assert image.size[0] > 200 and image.size[1] > 100


def test_ablation_table_gives_each_familys_cost():
    table = ablation_table(report()["ablation"])
    assert r"act & every family & 38.9 [" in table and "& 18 & +11.1 [" in table
    assert r"act 27.8\%" in table  # the full twin's rate, in the note


def test_ablation_figure_draws_a_policy_that_never_succeeds(tmp_path):
    rows = ablation_rows({"joints": episodes("act", 0, 6), "all": episodes("act", 6, 6)}, episodes("act", 0, 6), 0.95)
    save_figure(ablation_figure(rows, {"act": 0.0}, OPTS), tmp_path / "z.pdf", tmp_path / "z.png", dpi=60)
    assert (tmp_path / "z.png").stat().st_size > 0


def test_the_estimated_latency_is_reported_against_the_twins():
    from r2s_eval.report.fidelity_report import build_report

    reference = counts([("act", "cup_on_plate", 10, 18)])
    sim = pd.DataFrame({"policy": "act", "task": "cup_on_plate", "success": [k < 7 for k in range(18)]})
    calibrated = {"joints": {"estimated": True, "offsets_rad": {"left": [0.01]}, "latency_steps": 1}}
    built = build_report(reference, sim, sim, None, {}, {}, calibrated, {"left": [0.011]}, 0.95, 50, 0,
                         latency_truth=2)
    assert built["joints"]["latency"] == {"estimated_steps": 1, "truth_steps": 2}
    assert "commands' latency (control steps): estimated 1, twin 2" in format_report(built)
    # The twin's latency is in seconds (its reality effects): a fraction of a step where it falls mid-period.
    between = build_report(reference, sim, sim, None, {}, {}, calibrated, {"left": [0.011]}, 0.95, 50, 0,
                           latency_truth=0.15 * 10)
    assert between["joints"]["latency"] == {"estimated_steps": 1, "truth_steps": 1.5}
    assert "commands' latency (control steps): estimated 1, twin 1.5" in format_report(between)
    without = build_report(reference, sim, sim, None, {}, {}, {"joints": {"estimated": False}}, None, 0.95, 50, 0)
    assert "latency" not in without["joints"]

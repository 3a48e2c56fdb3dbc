"""The fidelity report's table, text and figure from a cross-evaluation."""

from __future__ import annotations

import numpy as np
import pytest
import pandas as pd
from PIL import Image

from r2s_eval.report import save_figure
from r2s_eval.report.tables import DASH
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


def _task_episodes(policy, successes, trials, task="cup_on_plate"):
    return pd.DataFrame({"policy": policy, "task": task, "init_id": range(trials),
                         "success": [k < successes for k in range(trials)]})


def test_the_crossing_in_further_sims_and_the_effects_alone():
    from r2s_eval.report.fidelity_report import alone_table, build_report, sims_table

    reference = counts([("act", "cup_on_plate", 10, 18), ("act_weak", "cup_on_plate", 0, 18)])
    s_sim, r_sim, s_real = _task_episodes("act", 12, 18), _task_episodes("act", 9, 18), _task_episodes("act", 6, 18)
    sims = {"nominal:real": _task_episodes("act", 2, 18), "nominal:sim": _task_episodes("act", 3, 18),
            "without_lens:real": _task_episodes("act", 8, 18)}
    alone = {"none": _task_episodes("act", 12, 18), "blur": _task_episodes("act", 9, 18),
             "walls": _task_episodes("act", 12, 18)}
    built = build_report(reference, s_sim, r_sim, s_real, {}, {}, {}, None, 0.95, 200, 0, sims=sims, alone=alone)

    nominal = built["sims"]["nominal"]
    # pi^R there minus pi^R on the real side: 2 - 10 of 18; pi^S on the real side minus there: 6 - 3 of 18.
    assert np.isclose(nominal["parts"]["calibration"]["mean_gap_pp"], 100 * (2 - 10) / 18)
    assert np.isclose(nominal["parts"]["calibration_reverse"]["mean_gap_pp"], 100 * (6 - 3) / 18)
    assert {c["policy"] for c in nominal["cells"]} == {"act"}  # act_weak has no checkpoint there
    assert set(built["sims"]["without_lens"]["parts"]) == {"calibration"}  # only pi^R ran there
    # Each effect against the twin with none: blur costs 3 of 18, walls nothing.
    costs = {r["family"]: r["cost_pp"] for r in built["alone"]}
    assert np.isclose(costs["blur"], -100 * 3 / 18) and costs["walls"] == 0 and "none" not in costs

    table = sims_table(built)
    rows = {line.split(" & ")[0]: line for line in table.splitlines() if " & " in line}
    assert rows["calibrated"].startswith("calibrated & 50.0 & -5.6 [") and "& 66.7 & -33.3 [" in rows["calibrated"]
    assert rows["nominal"].startswith("nominal & 11.1 & -44.4 [") and "& 16.7 & +16.7 [" in rows["nominal"]
    assert rows["without lens"].startswith("without lens & 44.4 & -11.1 [") and rows["without lens"].count(DASH) == 2
    assert r"$\pi^R$ 55.6\%, $\pi^S$ 33.3\%" in table  # the real side, in the note
    alone_tex = alone_table(built["alone"])
    assert "act & blur & 50.0 [" in alone_tex and "& -16.7 [" in alone_tex and "with the effect alone" in alone_tex
    text = format_report(built)
    assert "in nominal: calibration (R_sim - R_real)" in text
    assert "alone act with blur" in text and "cost -16.7 pp" in text


def test_effects_alone_need_the_twin_with_none():
    from r2s_eval.report.fidelity_report import alone_rows

    with pytest.raises(ValueError, match="the twin with 'none'"):
        alone_rows({"blur": _task_episodes("act", 9, 18)}, 0.95)


def test_the_crossing_over_every_training_of_a_recipe():
    # act's candidate and its further training seed 1, each in all four worlds from the same 18
    # inits per task: the crossing over both trainings averages their cells, paired over the inits.
    from r2s_eval.report.fidelity_report import build_report, sims_table

    def worlds(r_real, r_sim, s_sim, s_real, policy="act"):
        tasks = ("cup_on_plate", "cover_ball")
        return {w: pd.concat([_task_episodes(policy, k, 18, task) for task in tasks], ignore_index=True)
                for w, k in zip(("R_real", "R_sim", "S_sim", "S_real"), (r_real, r_sim, s_sim, s_real))}

    own, further = worlds(10, 8, 9, 9), worlds(6, 7, 12, 10)
    reference = own["R_real"].groupby(["policy", "task"], as_index=False)["success"].agg(
        successes="sum", trials="size")
    seed_episodes = {(w, 1): e for w, e in further.items()}
    built = build_report(reference, own["S_sim"], own["R_sim"], own["S_real"], {}, seed_episodes, {}, None, 0.95,
                         200, 0, real=own["R_real"])
    over = built["cross_trainings"]
    assert over["trainings"] == {"act": 2}
    calibration = over["parts"]["calibration"]
    # pi^R sim - real: the candidate's 8 - 10 and the seed's 7 - 6 of 18 in each of the two tasks
    assert calibration["cells"] == 4 and calibration["paired"]
    assert np.isclose(calibration["mean_gap_pp"], 100 * ((8 - 10) + (7 - 6)) / 2 / 18)
    assert np.isclose(over["training_means_pp"]["calibration"]["act"], 100 * -2 / 18)
    assert np.isclose(over["training_means_pp"]["calibration_reverse"]["act/1"], 100 * (10 - 12) / 18)
    # the candidate's own crossing is the one it always was; the seed's spread lists all four worlds
    assert np.isclose(built["cross"]["parts"]["calibration"]["mean_gap_pp"], 100 * -2 / 18)
    assert {s["world"] for s in built["seeds"]} == {"R_real", "R_sim", "S_sim", "S_real"}
    text = format_report(built)
    assert "over every training (act 2 trainings): calibration (R_sim - R_real)" in text
    assert "calibration per training (pp): act -11.1, act/1 +5.6" in text
    rows = {line.split(" & ")[0]: line for line in sims_table(built).splitlines() if " & " in line}
    assert rows["calibrated, every training"].startswith("calibrated, every training & 41.7 & -2.8 [")
    over_line = next(line for line in fidelity_table(built).splitlines() if "Over every training (act 2" in line)
    lo, hi = calibration["mean_gap_ci_pp"]
    assert f"mean {calibration['mean_gap_pp']:+.1f} pp [{lo:+.1f}, {hi:+.1f}]" in over_line
    # a further seed that ran only in its own worlds (no twin to cross into) adds no crossing over trainings
    only_own = {k: v for k, v in seed_episodes.items() if k[0] in ("R_real", "S_sim")}
    assert "cross_trainings" not in build_report(reference, own["S_sim"], own["R_sim"], own["S_real"], {}, only_own,
                                                 {}, None, 0.95, 50, 0, real=own["R_real"])


def _rollout_folder(path, policy, successes, trials):
    path.mkdir(parents=True)
    table = _task_episodes(policy, successes, trials).assign(video_path="v.mp4", trajectory_path="t.parquet")
    table.to_parquet(path / "episodes.parquet")
    return str(path)


def test_the_stage_reads_each_sim_and_effect_by_its_key_and_writes_their_tables(tmp_path):
    import argparse
    import json

    from r2s_eval.errors import DataError
    from r2s_eval.stages import fidelity

    reference = tmp_path / "success.parquet"
    counts([("act", "cup_on_plate", 10, 18)]).to_parquet(reference)
    world = tmp_path / "world_params.json"
    world.write_text(json.dumps({"params": {}}))
    folder = lambda name, k: _rollout_folder(tmp_path / name, "act", k, 18)  # noqa: E731
    args = argparse.Namespace(
        cfg={"stats.n_boot": 50, "stats.ci_level": 0.95, "seed": 0, "world.robot.control_hz": 10,
             "report.fidelity": {"decimals": 1}},
        reference=str(reference), sim=[folder("S_sim", 12)], cross_sim=[folder("R_sim", 9)], cross_real=[],
        real=[folder("R_real", 10)],
        ablation=[], seed_rollouts=[f"S_sim:1={folder('S_sim_seed1', 11)}"], twin=None, world_params=str(world),
        sims=[f"nominal:real={folder('nominal_R', 2)}", f"nominal:sim={folder('nominal_S', 3)}"],
        alone=[], out=str(tmp_path / "report.json"), table=str(tmp_path / "fidelity_table.tex"),
        sims_table=str(tmp_path / "sims.tex"), alone_table=None, ablation_table=None, pdf=None, png=None)
    fidelity.main(args)
    assert "nominal & 11.1 & -44.4 [" in (tmp_path / "sims.tex").read_text()
    written = json.loads((tmp_path / "report.json").read_text())
    assert set(written["sims"]) == {"nominal"} and written["seeds"][0]["seeds"] == [0, 1]
    # the reference's own episodes given: every part is paired over the shared inits, and says so
    assert all(part["paired"] for part in written["cross"]["parts"].values())
    assert all(part["paired"] for part in written["sims"]["nominal"]["parts"].values())
    assert "paired over the shared inits" in (tmp_path / "sims.tex").read_text()
    assert "intervals paired over the shared inits" in (tmp_path / "fidelity_table.tex").read_text()
    args.real = [folder("R_real_other", 11)]  # episodes that are not the reference's: refused, the cell named
    with pytest.raises(DataError, match="policy act, task cup_on_plate: the episodes"):
        fidelity.main(args)
    args.real = []
    args.sims = [folder("bad", 2)]  # no SIM:TRAINED_ON= before the folder: named, with what was expected
    with pytest.raises(DataError, match=r"--sims '.*bad': expected KEY=PATH"):
        fidelity.main(args)

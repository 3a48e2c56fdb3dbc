"""Report stage entry points on a small constructed run directory, with the real config slices."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from r2s_eval.config import compose_config, select, to_json
from r2s_eval.rollout.video import write_video
from r2s_eval.utils.io import read_json, write_json, write_parquet

CONF = Path(__file__).resolve().parents[2] / "conf"


@pytest.fixture(scope="module")
def cfg():
    return compose_config(CONF, experiment="smoke")


def run_stage(module: str, cfg: dict, slice_: str | None, *args: str) -> None:
    argv = [module] + (["--cfg", to_json(select(cfg, slice_))] if slice_ else []) + list(args)
    old = sys.argv
    sys.argv = argv
    try:
        runpy.run_module(f"r2s_eval.stages.{module}", run_name="__main__")
    finally:
        sys.argv = old


@pytest.fixture
def run_dir(tmp_path, verdicts, sim_episodes, make_fit, monkeypatch):
    """Artefacts shaped like a finished run's, for three policies and one judge."""
    monkeypatch.chdir(tmp_path)
    write_parquet("results/ingest/episodes.parquet", pd.DataFrame({"episode_index": [0, 1, 2], "task": ["cup_on_plate"] * 3}))
    write_parquet("results/replay/log.parquet", pd.DataFrame({"episode_index": [0, 1, 2], "task": ["cup_on_plate"] * 3,
                                                              "success": [True, True, False]}))
    write_parquet("results/reference/success.parquet", pd.DataFrame({
        "policy": ["a", "b", "c"], "task": ["cup_on_plate"] * 3, "trials": [2, 2, 2], "successes": [2, 1, 0]}))
    for policy, episodes in sim_episodes.groupby("policy"):
        folder = Path("results/rollout/sim") / policy
        for ep in episodes["episode_id"]:
            frames = [np.full((16, 16, 3), 20 * k, dtype=np.uint8) for k in range(8)]
            write_video(folder / "videos" / f"{ep}.mp4", frames, fps=10)
        write_parquet(folder / "episodes.parquet", episodes)
    write_parquet("results/judge/kin/verdicts.parquet", verdicts)
    write_parquet("results/fit/kin.parquet", make_fit({1: {"a": (50, 40, 60), "b": (30, 20, 40), "c": (20, 10, 30)},
                                                      2: {"a": (55, 45, 65), "b": (30, 20, 40), "c": (15, 8, 22)}}))
    metrics = {"spearman": 1.0, "pearson": 0.9, "mmrv": 0.0, "ci_width": 20.0}
    write_json("results/validate/kin.json", {"average": metrics, "last": metrics})
    pd.DataFrame({"episode_a": ["a1"], "episode_b": ["b1"], "choice": ["A"]}).to_csv("annotations.csv", index=False)
    return tmp_path


def test_tables_from_artefacts(run_dir, cfg):
    rollouts = [str(p) for p in sorted(Path("results/rollout/sim").iterdir())]
    run_stage("tasks_table", cfg, "report.tasks_table", "--index", "results/ingest/episodes.parquet",
              "--replay-log", "results/replay/log.parquet", "--out", "reports/tasks_table.tex")
    assert r"cup\_on\_plate & 3 & 2 & 66.7 \\" in Path("reports/tasks_table.tex").read_text()

    run_stage("realsim_success_table", cfg, "report.realsim_success_table", "--reference",
              "results/reference/success.parquet", "--rollouts", *rollouts, "--out", "reports/realsim_success_table.tex")
    assert r"a & 100.0 & 100.0 \\" in Path("reports/realsim_success_table.tex").read_text()

    run_stage("judge_audit", cfg, "report.judge_audit", "--judge", "kin", "--verdicts",
              "results/judge/kin/verdicts.parquet", "--rollouts", *rollouts, "--annotations", "annotations.csv",
              "--out", "results/audit/kin.json")
    audit = read_json("results/audit/kin.json")
    assert audit["human_agreement"] == 1.0 and audit["swap_consistency"] is None and audit["judge"] == "kin"

    run_stage("realsim_table", cfg, "report.realsim_table", "--validation", "results/validate/kin.json",
              "--audits", "results/audit/kin.json", "--fits", "results/fit/kin.parquet", "--reference",
              "results/reference/success.parquet", "--table", "reports/realsim_table.tex",
              "--ranking", "reports/ranking.txt")
    assert r"kin & 1.000 & 0.900 & 0.000 & 20.000 & 1.000 & -- & 0.500 \\" in Path("reports/realsim_table.tex").read_text()

    run_stage("bt_scores_table", cfg, "report.bt_scores_table", "--fits", "results/fit/kin.parquet",
              "--reference", "results/reference/success.parquet", "--out", "reports/bt_scores_table.tex")
    assert r"a & 100.0 & 55.0 {\scriptsize [45.0, 65.0]} \\" in Path("reports/bt_scores_table.tex").read_text()


def test_figures_from_artefacts(run_dir, cfg):
    rollouts = [str(p) for p in sorted(Path("results/rollout/sim").iterdir())]
    runs = {
        "win_rate_matrix_kin": ("win_rate_figure", "report.win_rate_matrix", "--judge", "kin", "--verdicts",
                                "results/judge/kin/verdicts.parquet"),
        "bt_convergence": ("bt_convergence_figure", "report.bt_convergence", "--fits", "results/fit/kin.parquet"),
        "overall_ranking": ("overall_ranking_figure", "report.overall_ranking", "--fits", "results/fit/kin.parquet",
                            "--reference", "results/reference/success.parquet"),
        "hardware_effort": ("hardware_effort_figure", "report.hardware_effort", "--reference",
                            "results/reference/success.parquet"),
        "case_study_kin": ("case_study_figure", "report.case_study", "--judge", "kin", "--verdicts",
                           "results/judge/kin/verdicts.parquet", "--rollouts", *rollouts),
    }
    for name, (module, slice_, *args) in runs.items():
        run_stage(module, cfg, slice_, *args, "--pdf", f"reports/{name}.pdf", "--png", f"reports/{name}.png")
        assert Path(f"reports/{name}.pdf").read_bytes().startswith(b"%PDF")
        assert Path(f"reports/{name}.png").stat().st_size > 1000

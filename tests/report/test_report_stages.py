"""Report stage entry points on a small constructed run directory, with the real config slices."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from r2s_eval.config import compose_config, select, to_json
from r2s_eval.rollout.mp4 import write_video
from r2s_eval.stages._reads import declaration
from r2s_eval.utils.io import read_json, write_json, write_parquet

CONF = Path(__file__).resolve().parents[2] / "conf"


@pytest.fixture(scope="module")
def cfg():
    return compose_config(CONF, experiment="smoke")


def run_stage(module: str, cfg: dict, slice_: str | tuple[str, ...] | None, *args: str) -> None:
    slices = (slice_,) if isinstance(slice_, str) else slice_
    argv = [module] + (["--cfg", to_json(select(cfg, *slices))] if slices else []) + list(args)
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
    reference = {"success_rate": {"a": 1.0, "b": 0.5, "c": 0.0}, "ci_low": {"a": 1.0, "b": 0.0, "c": 0.0},
                 "ci_high": {"a": 1.0, "b": 1.0, "c": 0.0}}
    write_json("results/validate/kin.json", {"average": metrics, "last": metrics, "interval": "binomial",
                                              "ci_level": 0.95, "reference": reference})
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

    run_stage("judge_audit", cfg, declaration("judge_audit")["READS"], "--judge", "kin", "--verdicts",
              "results/judge/kin/verdicts.parquet", "--rollouts", *rollouts, "--annotations", "annotations.csv",
              "--out", "results/audit/kin.json")
    audit = read_json("results/audit/kin.json")
    assert audit["human_agreement"] == 1.0 and audit["swap_consistency"] is None and audit["judge"] == "kin"
    assert audit["outcome_agreement"]["share"] == 0.75 and audit["outcome_agreement"]["n_pairs"] == 4
    # The configured planted order names the CPU line-up, none of which is here.
    assert audit["planted_order_agreement"]["share"] is None
    assert audit["planted_order_agreement"]["n_unranked_pairs"] == 1  # the one pair that both succeeded
    assert audit["shuffled_label_control"]["n_permutations"] == cfg["report"]["judge_audit"]["shuffled_permutations"]

    run_stage("judge_card_table", cfg, "report.judge_card_table", "--audits", "results/audit/kin.json",
              "--out", "reports/judge_card_table.tex")
    card = Path("reports/judge_card_table.tex").read_text()
    made_by, body = card.split("\n", 1)  # first line: the provenance, as a LaTeX comment
    assert made_by.startswith("% config_sha256=") and "r2s_eval_version=" in made_by
    assert body.startswith(r"\begin{tabular}") and r"kin & 75.0 {\scriptsize [" in body

    run_stage("realsim_table", cfg, ("report.realsim_table", "report.judge_audit.planted_order"),
              "--validation", "results/validate/kin.json",
              "--audits", "results/audit/kin.json", "--fits", "results/fit/kin.parquet", "--reference",
              "results/reference/success.parquet", "--table", "reports/realsim_table.tex",
              "--ranking", "reports/ranking.txt")
    assert r"kin & 1.000 & 0.900 & 0.000 & 20.000 & 1.000 & -- & 0.500 \\" in Path("reports/realsim_table.tex").read_text()
    assert "50.0 [0.0, 100.0]" in Path("reports/ranking.txt").read_text()  # b's reference with its CI

    run_stage("bt_scores_table", cfg, "report.bt_scores_table", "--fits", "results/fit/kin.parquet",
              "--reference", "results/reference/success.parquet", "--out", "reports/bt_scores_table.tex")
    assert r"a & 100.0 & 55.0 {\scriptsize [45.0, 65.0]} \\" in Path("reports/bt_scores_table.tex").read_text()
    run_stage("bt_scores_table", cfg, "report.bt_scores_table", "--fits", "results/fit/kin.parquet",
              "--reference", "results/reference/success.parquet", "--validation", "results/validate/kin.json",
              "--out", "reports/bt_scores_table.tex")
    assert r"b & 50.0 {\scriptsize [0.0, 100.0]} & 30.0 {\scriptsize [20.0, 40.0]} \\" in Path(
        "reports/bt_scores_table.tex").read_text()


def test_figures_from_artefacts(run_dir, cfg):
    rollouts = [str(p) for p in sorted(Path("results/rollout/sim").iterdir())]
    runs = {
        "win_rate_matrix_kin": ("win_rate_figure", "report.win_rate_matrix", "--judge", "kin", "--verdicts",
                                "results/judge/kin/verdicts.parquet"),
        "bt_convergence": ("bt_convergence_figure", "report.bt_convergence", "--fits", "results/fit/kin.parquet"),
        "overall_ranking": ("overall_ranking_figure", "report.overall_ranking", "--fits", "results/fit/kin.parquet",
                            "--reference", "results/reference/success.parquet", "--validation",
                            "results/validate/kin.json"),
        "hardware_effort": ("hardware_effort_figure", "report.hardware_effort", "--reference",
                            "results/reference/success.parquet"),
        "case_study_kin": ("case_study_figure", "report.case_study", "--judge", "kin", "--verdicts",
                           "results/judge/kin/verdicts.parquet", "--rollouts", *rollouts),
    }
    for name, (module, slice_, *args) in runs.items():
        run_stage(module, cfg, slice_, *args, "--pdf", f"reports/{name}.pdf", "--png", f"reports/{name}.png")
        assert Path(f"reports/{name}.pdf").read_bytes().startswith(b"%PDF")
        assert Path(f"reports/{name}.png").stat().st_size > 1000


def judged(rng: np.random.Generator, n: int = 30) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Verdicts shaped like judge_pairs output for three policies, two tasks and three inits per
    task: every (pair, task, init) is one rollout pair with its own latent preference, judged
    again whenever it is drawn. Also the pairs table they were judged on."""
    theta = {"a": 0.8, "b": 0.0, "c": -0.8}
    rows = []
    for pi, pj in (("a", "b"), ("a", "c"), ("b", "c")):
        latent = {}
        for k in range(n):
            task, init = ["cup_on_plate", "stack"][k % 2], int(rng.integers(3))
            p = latent.setdefault((task, init), 1 / (1 + np.exp(-(theta[pi] - theta[pj] + rng.normal(0, 4)))))
            pa, pb = (pi, pj) if k % 2 else (pj, pi)
            win_i = rng.random() < p
            winner = pi if win_i else pj
            rows.append({"pair_index": k, "policy_i": pi, "policy_j": pj, "task": task, "init_id": init,
                         "episode_a": f"{pa}-{task}-{init}", "episode_b": f"{pb}-{task}-{init}", "policy_a": pa,
                         "policy_b": pb, "first_checkpoint": 10 * (k // 10 + 1),
                         "verdict": "A" if winner == pa else "B", "winner": winner})
    verdicts = pd.DataFrame(rows)
    return verdicts, verdicts[list(verdicts.columns[:10])]


@pytest.mark.filterwarnings("ignore:.*did not converge:RuntimeWarning")  # a few replicates at the boundary
@pytest.mark.filterwarnings("ignore:.*found in sys.modules:RuntimeWarning")  # runpy after an import
def test_fit_and_validate_store_both_intervals_and_metric_cis(tmp_path, monkeypatch, cfg):
    monkeypatch.chdir(tmp_path)
    verdicts, pairs = judged(np.random.default_rng(0))
    write_parquet("verdicts.parquet", verdicts)
    write_parquet("pairs.parquet", pairs)
    # Policy a: 1.0 and 0.5 on the two tasks (mean 0.75), though pooled trials would give 9/12.
    write_parquet("success.parquet", pd.DataFrame({
        "policy": ["a", "a", "b", "b", "c", "c"], "task": ["cup_on_plate", "stack"] * 3,
        "trials": [8, 4, 6, 6, 6, 6], "successes": [8, 2, 3, 3, 0, 1]}))
    run_stage("fit", cfg, declaration("fit")["READS"], "--verdicts", "verdicts.parquet", "--pairs", "pairs.parquet",
              "--out", "fit.parquet", "--replicates", "replicates.parquet")
    fit = pd.read_parquet("fit.parquet")
    assert sorted(fit["checkpoint"].unique()) == [10, 20, 30] and (fit["interval"] == "unit").all()
    np.testing.assert_array_equal(fit["ci_low"], fit["ci_low_unit"])
    np.testing.assert_array_equal(fit["ci_high"], fit["ci_high_unit"])
    assert (fit["ci_low_binomial"] <= fit["score"]).all() and (fit["score"] <= fit["ci_high_binomial"]).all()
    # Six rollout pairs per policy pair judged five times each: the unit intervals are wider.
    last = fit[fit["checkpoint"] == 30]
    assert (last["units"] == 12).all()  # two policy pairs, six (task, init) each
    unit_w = (last["ci_high_unit"] - last["ci_low_unit"]).mean()
    assert unit_w > 1.2 * (last["ci_high_binomial"] - last["ci_low_binomial"]).mean()
    replicates = pd.read_parquet("replicates.parquet")
    n_boot = cfg["stats"]["n_boot"]
    assert len(replicates) == 2 * 3 * n_boot * 3 and set(replicates["interval"]) == {"unit", "binomial"}
    boot = replicates[(replicates["interval"] == "unit") & (replicates["checkpoint"] == 30)]
    lows = (100 * boot.pivot(index="replicate", columns="policy", values="strength")).quantile(0.025)
    np.testing.assert_allclose(last.set_index("policy")["ci_low"], lows.loc[["a", "b", "c"]], rtol=1e-9)

    run_stage("validate", cfg, declaration("validate")["READS"], "--fit", "fit.parquet", "--replicates", "replicates.parquet",
              "--reference", "success.parquet", "--out", "validate.json")
    result = read_json("validate.json")
    assert result["interval"] == "unit" and result["ci_level"] == 0.95
    assert result["reference"]["success_rate"]["a"] == pytest.approx(0.75)
    assert result["reference"]["ci_low"]["a"] < 0.75 < result["reference"]["ci_high"]["a"]
    assert [r["checkpoint"] for r in result["per_checkpoint"]] == [10, 20, 30]
    for record in result["per_checkpoint"] + [result["last"]]:
        for m in ("spearman", "pearson", "mmrv"):
            assert record[f"{m}_ci_low"] <= record[f"{m}_ci_high"]
            assert record[f"{m}_ci_low_with_reference"] <= record[f"{m}_ci_high_with_reference"]
        assert record["ci_width"] == pytest.approx(record["ci_width_unit"])
        assert record["ci_width_unit"] > record["ci_width_binomial"]
    # Coupled unit replicates: the average over checkpoints has an interval too.
    assert result["average"]["spearman_ci_low"] is not None
    assert "against_networks_in_twin" not in result

    # The checkpoints the sim ranks, rolled out in the twin (a and b: c's weights came from
    # elsewhere): the same metrics against their success there, beside the real reference's.
    for policy, wins in (("a", [1, 0, 0, 0]), ("b", [1, 1, 1, 0])):
        Path(f"twin/{policy}").mkdir(parents=True)
        write_parquet(f"twin/{policy}/episodes.parquet", pd.DataFrame({
            "policy": policy, "task": ["cup_on_plate", "cup_on_plate", "stack", "stack"], "success": wins}))
    run_stage("validate", cfg, declaration("validate")["READS"], "--fit", "fit.parquet", "--replicates", "replicates.parquet",
              "--reference", "success.parquet", "--networks-in-twin", "twin/a", "twin/b", "--out", "validate_t.json")
    twin = read_json("validate_t.json")
    assert {k: v for k, v in twin.items() if k not in ("against_networks_in_twin", "provenance")} == \
        {k: v for k, v in result.items() if k != "provenance"}
    networks = twin["against_networks_in_twin"]
    assert networks["policies"] == ["a", "b"]
    assert networks["reference_success_rate"] == {"a": pytest.approx(0.25), "b": pytest.approx(0.75)}
    scores = fit[fit["checkpoint"] == 30].set_index("policy")["score"]
    assert networks["last"]["spearman"] == pytest.approx(1.0 if scores["b"] > scores["a"] else -1.0)
    assert networks["last"]["spearman_ci_low"] <= networks["last"]["spearman_ci_high"]

    # Choosing the binomial interval: the same stored intervals, the other one shown.
    binomial_cfg = compose_config(CONF, experiment="smoke", overrides=["stats.interval=binomial"])
    run_stage("fit", binomial_cfg, declaration("fit")["READS"], "--verdicts", "verdicts.parquet",
              "--pairs", "pairs.parquet", "--out", "fit_b.parquet", "--replicates", "replicates_b.parquet")
    fit_b = pd.read_parquet("fit_b.parquet")
    assert (fit_b["interval"] == "binomial").all()
    np.testing.assert_array_equal(fit_b["ci_low"], fit_b["ci_low_binomial"])
    np.testing.assert_array_equal(fit_b["ci_low_unit"], fit["ci_low_unit"])
    run_stage("validate", binomial_cfg, declaration("validate")["READS"], "--fit", "fit_b.parquet", "--replicates",
              "replicates_b.parquet", "--reference", "success.parquet", "--out", "validate_b.json")
    result_b = read_json("validate_b.json")
    assert result_b["interval"] == "binomial" and result_b["average"]["spearman_ci_low"] is None
    assert result_b["reference"] == result["reference"]  # the same seeded reference bootstrap


def test_fit_takes_units_from_the_pairs_and_checks_them():
    from r2s_eval.stats import with_units

    verdicts, pairs = judged(np.random.default_rng(1), n=10)
    filled = with_units(verdicts.drop(columns=["task", "init_id"]), pairs)
    pd.testing.assert_series_equal(filled["init_id"], verdicts["init_id"])
    stale = pairs.assign(task=pairs["task"].where(pairs["pair_index"] != 3, "other"))
    with pytest.raises(ValueError, match="disagree on the task"):
        with_units(verdicts, stale)
    with pytest.raises(ValueError, match="no pairs table"):
        with_units(verdicts.drop(columns=["init_id"]))

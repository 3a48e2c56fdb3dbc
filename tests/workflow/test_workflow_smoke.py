"""The smoke experiment end to end: outputs, rerun scope of config changes, kill and resume."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections import Counter

import pandas as pd
import pytest

from .conftest import finished_rules, planned_jobs, snakemake

pytestmark = pytest.mark.slow

# Reports drawn from the Bradley-Terry fits, and those drawn from the verdicts themselves.
FIT_REPORTS = {"bt_scores_table", "bt_convergence", "overall_ranking"}
VERDICT_REPORTS = {"win_rate_matrix", "case_study"}


def test_report_has_real_numbers(smoke_run):
    table = (smoke_run.workdir / "reports" / "realsim_table.tex").read_text()
    assert r"\toprule" in table and "kinematic" in table
    validation = json.loads((smoke_run.workdir / "results" / "validate" / "kinematic.json").read_text())
    for metric in ("spearman", "pearson", "mmrv", "ci_width"):
        assert metric in validation["average"]
    ranking = (smoke_run.workdir / "reports" / "ranking.txt").read_text()
    assert "act_weak" in ranking and "real success %" in ranking
    reference = pd.read_parquet(smoke_run.workdir / "results" / "reference" / "success.parquet")
    assert set(reference["policy"]) == {"act", "act_subset", "act_weak"}
    assert (reference["trials"] > 0).all()
    # Six rollouts per policy cannot order the policies significantly (the demo's reference is
    # where orderings are judged); what must hold is that the reference is exactly what the
    # real-side rollouts recorded, per policy and task.
    for row in reference.itertuples():
        episodes = pd.read_parquet(smoke_run.workdir / "results" / "rollout" / "real" / row.policy / "episodes.parquet")
        episodes = episodes[episodes["task"] == row.task]
        assert row.trials == len(episodes) == 6
        assert row.successes == int(episodes["success"].sum())
        assert row.success_rate == pytest.approx(row.successes / row.trials)
        assert f"{100 * row.success_rate:.1f}" in ranking, (row.policy, ranking)


def test_each_stage_contract(smoke_run):
    results = smoke_run.workdir / "results"
    index = pd.read_parquet(results / "ingest" / "episodes.parquet")
    assert len(index) == 8 and set(index["task"]) == {"cup_on_plate"}
    estimates = pd.read_parquet(results / "init" / "estimates.parquet")
    assert set(estimates["object"]) == {"cup", "plate"} and len(estimates) == 2 * len(index)
    replay = pd.read_parquet(results / "replay" / "log.parquet")
    assert replay["attempts"].between(1, 9).all() and replay["success"].any()
    for arm in ("real", "sim"):
        for policy in ("act", "act_subset", "act_weak"):
            folder = results / "rollout" / arm / policy
            episodes = pd.read_parquet(folder / "episodes.parquet")
            assert len(episodes) == 6
            for ep in episodes.itertuples():
                assert (folder / ep.video_path).stat().st_size > 0
                assert len(pd.read_parquet(folder / ep.trajectory_path)) == ep.length
    pairs = pd.read_parquet(results / "compare" / "pairs.parquet")
    assert (pairs.groupby(["policy_i", "policy_j"]).size() == 30).all()
    verdicts = pd.read_parquet(results / "judge" / "kinematic" / "verdicts.parquet")
    assert set(verdicts["verdict"]) <= {"A", "B"} and len(verdicts) == len(pairs)


def test_kill_and_resume_redoes_only_unfinished_jobs(smoke_run):
    first, second = smoke_run.killed_after
    assert first and second, "nothing had finished before a kill"
    # Each run after a kill must not redo what had finished (and was recorded) before it.
    later_runs = [smoke_run.first_resume_output + smoke_run.resumed_output, smoke_run.resumed_output]
    for finished, later in zip((first, second), later_runs):
        redone = Counter(finished_rules(later))
        for rule in set(finished) - {"train", "rollout"}:
            assert redone[rule] == 0, f"{rule} finished before a kill but ran again"
    # No half-written artefact is left where a finished one belongs.
    for leftover in smoke_run.workdir.joinpath("results").rglob("*.tmp"):
        assert leftover.name.startswith("."), leftover


def test_job_killed_before_it_was_recorded_is_redone(smoke_run):
    # Ingest had written every output when the first run died, but Snakemake never recorded
    # the job: the plain command must redo it rather than stop on incomplete files.
    assert smoke_run.ingest_outputs_at_kill == ["episodes.parquet", "first_frames", "report.json"]
    assert "ingest" not in smoke_run.killed_after[0]
    assert "IncompleteFilesException" not in smoke_run.first_resume_output
    assert "Finished jobid" in smoke_run.first_resume_output
    assert "ingest" in finished_rules(smoke_run.first_resume_output)


def test_second_invocation_plans_nothing(smoke_run):
    proc = snakemake(smoke_run.workdir, "-n")
    assert planned_jobs(proc.stdout) == [], proc.stdout[-2000:]


def test_statistics_change_reruns_only_fit_onward(smoke_run):
    proc = snakemake(smoke_run.workdir, "-n", overrides=["stats.n_boot=150"])
    rules = {rule for rule, _ in planned_jobs(proc.stdout)}
    assert rules == {"fit", "validate", "realsim_table", *FIT_REPORTS}, rules


def test_judge_change_reruns_describe_onward(smoke_run):
    proc = snakemake(smoke_run.workdir, "-n", overrides=["+judges.kinematic.progress_margin=0.07"])
    rules = {rule for rule, _ in planned_jobs(proc.stdout)}
    expected = {"describe", "judge_pairs", "fit", "validate", "realsim_table", "judge_audit", "judge_card_table", *FIT_REPORTS, *VERDICT_REPORTS}
    assert rules == expected, rules


def test_plot_option_reruns_only_that_figure(smoke_run):
    proc = snakemake(smoke_run.workdir, "-n", overrides=["report.win_rate_matrix.cmap=viridis"])
    assert {rule for rule, _ in planned_jobs(proc.stdout)} == {"win_rate_matrix"}


def test_policy_change_reruns_only_that_policy(smoke_run):
    proc = snakemake(smoke_run.workdir, "-n", overrides=["policies.act_weak.lr=0.0002"])
    jobs = planned_jobs(proc.stdout)
    per_policy = {(rule, wc.get("policy")) for rule, wc in jobs if "policy" in wc}
    assert per_policy == {("train", "act_weak"), ("rollout", "act_weak")}, per_policy
    assert not {rule for rule, _ in jobs} & {"twin", "teleop", "ingest", "init_estimate", "replay", "rollout_inits"}


def test_dvc_round_trip_plans_nothing(smoke_run, tmp_path):
    wd = smoke_run.workdir
    subprocess.run(["dvc", "init", "--no-scm", "-q"], cwd=wd, check=True)
    subprocess.run(["dvc", "remote", "add", "-d", "store", str(tmp_path / "remote")], cwd=wd, check=True)
    run = [sys.executable, "-m", "r2s_eval.artifacts"]
    subprocess.run([*run, "push", "--root", str(wd)], check=True, capture_output=True)
    shutil.rmtree(wd / "results" / "real" / "dataset")
    shutil.rmtree(wd / "results" / "train")
    (wd / "reports" / "realsim_table.tex").unlink()
    subprocess.run([*run, "pull", "--root", str(wd)], check=True, capture_output=True)
    assert (wd / "reports" / "realsim_table.tex").exists()
    proc = snakemake(wd, "-n")
    assert planned_jobs(proc.stdout) == [], proc.stdout[-2000:]

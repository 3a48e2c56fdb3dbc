"""The smoke experiment through Snakemake's Slurm executor, on a real Slurm started by the test."""

from __future__ import annotations

import re

import pytest

from ..workflow.conftest import assert_same_outputs, planned_jobs
from .conftest import CANCELLED, run, site_profile, slurm_comment, slurm_snakemake

pytestmark = [pytest.mark.slow, pytest.mark.slurm]


def _jobs(plan: list[tuple[str, dict]]) -> set[str]:
    return {slurm_comment(rule, wildcards) for rule, wildcards in plan}


def _seconds(value: str) -> float:
    """sacct's [DD-][HH:]MM:SS[.fff] as seconds."""
    days, _, clock = value.rpartition("-")
    parts = [float(p) for p in clock.split(":")]
    while len(parts) < 3:
        parts.insert(0, 0.0)
    return (int(days) if days else 0) * 86400 + parts[0] * 3600 + parts[1] * 60 + parts[2]


def test_slurm_run_gives_the_local_bytes(slurm_smoke, smoke_run):
    # Same config through Slurm (and a cancel and a rerun in between), the README's target: the
    # same reports, byte for byte, and the same tables as the local run made for them.
    assert slurm_smoke.rerun.returncode == 0, slurm_smoke.rerun.stdout[-4000:] + slurm_smoke.rerun.stderr[-4000:]
    assert (slurm_smoke.workdir / "reports" / "realsim_table.tex").exists()
    assert_same_outputs(smoke_run.workdir, slurm_smoke.workdir, part=True)


def test_sacct_lists_the_jobs_that_made_the_outputs(slurm, slurm_smoke, tmp_path):
    # Every job of the smoke's DAG ran as a Slurm job that accounting recorded as completed, under
    # the account of the site profile; the cancelled one is recorded as cancelled.
    fresh = run(slurm, [*slurm_snakemake(slurm, tmp_path / "fresh", slurm_smoke.profile), "-n"])
    expected = _jobs([(r, w) for r, w in planned_jobs(fresh.stdout) if r not in {"reports"}])
    records = slurm.accounting("JobID", "Comment", "State", "Account", "Partition")
    completed = {r["Comment"] for r in records if r["State"] == "COMPLETED"}
    assert len(expected) > 30 and expected <= completed, sorted(expected - completed)
    assert all(r["Account"] == slurm.account and r["Partition"] == slurm.partition for r in records)
    cancelled = [r for r in records if r["JobID"] == slurm_smoke.cancelled_jobid]
    assert cancelled and cancelled[0]["State"].startswith("CANCELLED")
    assert cancelled[0]["Comment"] == slurm_comment(*CANCELLED)


def test_cancelled_job_fails_the_run_and_the_rerun_submits_only_it_and_its_dependants(slurm, slurm_smoke):
    first = slurm_smoke.first.stdout
    assert slurm_smoke.first.returncode != 0
    # Snakemake names the rule, the job's output and the Slurm job, and says it was cancelled.
    error = first[first.index("Error in rule train"):][:3000]
    assert f"SLURM-job '{slurm_smoke.cancelled_jobid}' failed" in error and "CANCELLED" in error, error
    assert "output: results/train/sim/act\n" in error, error
    # What depends on the cancelled job, as Snakemake itself computes it on the finished run.
    forced = run(slurm, [*slurm_snakemake(slurm, slurm_smoke.workdir, slurm_smoke.profile), "-n",
                         "--forcerun", "results/train/sim/act"])
    dependants = _jobs(planned_jobs(forced.stdout))
    assert slurm_comment(*CANCELLED) in dependants and len(dependants) < 40
    assert _jobs(slurm_smoke.plan_after_cancel) == dependants
    # And the rerun submitted exactly those jobs to Slurm, nothing the first run had finished.
    records = slurm.accounting("JobID", "Comment", "State")
    # Snakemake logs the submissions on stderr (the first run's log file holds both streams).
    rerun_ids = set(re.findall(r"submitted with SLURM jobid (\d+)", slurm_smoke.rerun.stdout + slurm_smoke.rerun.stderr))
    assert len(rerun_ids) == len(dependants)
    assert {r["Comment"] for r in records if r["JobID"] in rerun_ids} == dependants
    assert not rerun_ids & slurm_smoke.first_jobids


def test_jobs_use_no_more_cpu_than_they_were_given(slurm, slurm_smoke):
    # CPU time a job's processes used, against its allocation times its wall time (plus a second:
    # sacct rounds Elapsed to whole seconds). Slurm here schedules CPUs without confining them,
    # so a stage whose thread pools ignored its job's threads would show up here. The margin
    # covers the job step's own Snakemake process beside the stage (measured: up to 1.01 of the
    # budget on two cores); a pool sized by the machine's CPUs shows as a multiple of it.
    used, over = {}, []
    for r in slurm.accounting("JobID", "Comment", "State", "AllocCPUS", "Elapsed", "TotalCPU"):
        if r["State"] == "COMPLETED" and r["JobID"] in slurm_smoke.first_jobids:
            budget = int(r["AllocCPUS"]) * (_seconds(r["Elapsed"]) + 1.0)
            used[r["Comment"]] = _seconds(r["TotalCPU"])
            if used[r["Comment"]] > 1.2 * budget:
                over.append((r["Comment"], r["AllocCPUS"], r["Elapsed"], r["TotalCPU"]))
    # Accounting did record the jobs' CPU time (training takes tens of CPU-seconds at least).
    assert used and max(used.values()) > 10.0, used
    assert over == []


@pytest.mark.parametrize("setting", ["slurm_partition", "slurm_account"])
def test_unknown_partition_or_account_reaches_the_user_with_rule_and_job(slurm, tmp_path, setting):
    profile = site_profile(tmp_path / "site", slurm, **{
        "default-resources": {"slurm_partition": slurm.partition, "slurm_account": slurm.account, setting: "nosuch"}})
    proc = run(slurm, slurm_snakemake(slurm, tmp_path / "run", profile, "results/real/twin_params.json"), 600)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "Error in rule twin" in out, out[-4000:]
    error = out[out.index("Error in rule twin"):].split("Exiting because")[0]
    assert "jobid: " in error and "results/real/twin_params.json" in error, error
    if setting == "slurm_partition":  # sbatch's own words
        assert "invalid partition specified: nosuch" in error, error
    else:  # checked against Slurm's accounts before sbatch, which lists them
        assert "account nosuch appears to be invalid" in error and slurm.account in error, error
    assert not (tmp_path / "run" / "results" / "real" / "twin_params.json").exists()

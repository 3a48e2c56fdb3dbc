"""The smoke experiment on a real single-node Slurm, started by the test (see tests/helpers/slurm.py).

One run goes through `--profile workflow/profiles/slurm` plus a site profile for this cluster
(its partition and account, and the default profile's job sizes in place of the paper-scale ones:
the node has the machine's few CPUs and little memory). While it runs, the sim-arm training of one
policy is cancelled with `scancel`; the run carries on with what does not depend on it and fails.
The plain command is then run again, which must submit only that job and what depends on it.
"""

from __future__ import annotations

import importlib.util
import os
import re
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from tests.helpers.slurm import PACKAGES, LocalSlurm, missing_binaries

from ..workflow.conftest import REPO, SNAKEMAKE, planned_jobs, smoke_run  # noqa: F401  (smoke_run: a fixture)

RUN_TIMEOUT_S = 2400
CANCELLED = ("train", {"arm": "sim", "policy": "act"})  # has the longest training of the smoke


def slurm_comment(rule: str, wildcards: dict) -> str:
    """The comment the executor plugin gives a job's sbatch (sacct keeps it): rule and wildcard
    values in the order of the rule's output pattern (dry runs print them in that order)."""
    return f"rule_{rule}" + (f"_wildcards_{'_'.join(wildcards.values())}" if wildcards else "")


def site_profile(folder: Path, slurm: LocalSlurm, **settings) -> Path:
    """A profile for this cluster, given after workflow/profiles/slurm: its partition and account,
    and the default profile's threads and sizes in place of the slurm profile's paper-scale ones."""
    default = yaml.safe_load((REPO / "workflow" / "profiles" / "default" / "config.yaml").read_text())
    profile = {
        "default-resources": {"slurm_partition": slurm.partition, "slurm_account": slurm.account},
        "set-threads": default["set-threads"],
        "set-resources": default["set-resources"],
        "retries": 0,  # a cancelled job must fail, not come back on its own
        "slurm-init-seconds-before-status-checks": 5,
        **settings,
    }
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "config.yaml").write_text(yaml.safe_dump(profile, sort_keys=False))
    return folder


SLURM_TARGET = "reports/realsim_table.tex"


def slurm_snakemake(slurm: LocalSlurm, workdir: Path, profile: Path, *targets: str) -> list[str]:
    # The README's target by default: the local smoke run already covers the rest of the DAG, and
    # the Slurm run needs enough of it to cancel a training and resume.
    return [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(workdir),
            "--profile", str(REPO / "workflow" / "profiles" / "slurm"), "--profile", str(profile),
            *(targets or [SLURM_TARGET]),
            "--config", "experiment=smoke"]


def run(slurm: LocalSlurm, cmd: list[str], timeout_s: float = RUN_TIMEOUT_S) -> subprocess.CompletedProcess:
    # Snakemake runs in the repository so that `--profile workflow/profiles/slurm` resolves as documented.
    return subprocess.run(cmd, cwd=REPO, env=slurm.env(), capture_output=True, text=True, timeout=timeout_s)


@pytest.fixture(scope="session")
def slurm(tmp_path_factory):
    missing = missing_binaries()
    if missing:
        pytest.skip(f"no Slurm here ({', '.join(missing)} missing): apt-get install {PACKAGES}")
    if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
        pytest.skip("snakemake-executor-plugin-slurm is not installed (see docs/cluster.md)")
    # A short path: munge's socket path must fit a sockaddr_un.
    with LocalSlurm(tmp_path_factory.mktemp("slurm")) as cluster:
        yield cluster


@dataclass
class SlurmSmoke:
    workdir: Path
    profile: Path
    cancelled_jobid: str
    first: subprocess.CompletedProcess  # the run whose job was cancelled
    plan_after_cancel: list[tuple[str, dict]]  # what a dry run then plans
    rerun: subprocess.CompletedProcess
    first_jobids: set[str]  # Slurm jobs submitted by the first run
    wall_s: float


def _cancel_when_running(slurm: LocalSlurm, proc: subprocess.Popen, workdir: Path, log_path: Path) -> str:
    """scancel the CANCELLED job once its stage is running inside Slurm (its log exists)."""
    rule, wildcards = CANCELLED
    comment = slurm_comment(rule, wildcards)
    stage_log = workdir / "logs" / rule / wildcards["arm"] / f"{wildcards['policy']}.log"
    deadline = time.monotonic() + RUN_TIMEOUT_S
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the run ended before {comment} ran:\n{log_path.read_text()[-4000:]}"
        queue = slurm.run("squeue", "-h", "-o", "%i|%k|%T", check=False).stdout
        running = [line.split("|")[0] for line in queue.splitlines() if line.split("|")[1:] == [comment, "RUNNING"]]
        if running and stage_log.exists():
            slurm.run("scancel", running[0])
            return running[0]
        time.sleep(1)
    raise AssertionError(f"{comment} did not run within {RUN_TIMEOUT_S} s")


@pytest.fixture(scope="session")
def slurm_smoke(slurm, tmp_path_factory) -> SlurmSmoke:
    root = tmp_path_factory.mktemp("slurm_smoke")
    workdir, profile = root / "run", site_profile(root / "site", slurm)
    cmd = slurm_snakemake(slurm, workdir, profile)
    start = time.monotonic()
    log_path = root / "first_run.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, cwd=REPO, env=slurm.env(), stdout=log, stderr=subprocess.STDOUT, text=True,
                                start_new_session=True)
        try:
            jobid = _cancel_when_running(slurm, proc, workdir, log_path)
            proc.wait(timeout=RUN_TIMEOUT_S)
        finally:
            if proc.poll() is None:  # a hung run: end it and its children
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    first = subprocess.CompletedProcess(cmd, proc.returncode, log_path.read_text(), "")
    first_jobids = set(re.findall(r"submitted with SLURM jobid (\d+)", first.stdout))
    plan = run(slurm, [*cmd, "-n"])
    assert plan.returncode == 0, plan.stdout[-3000:] + plan.stderr[-3000:]
    rerun = run(slurm, cmd)
    return SlurmSmoke(workdir, profile, jobid, first, planned_jobs(plan.stdout), rerun, first_jobids,
                      time.monotonic() - start)

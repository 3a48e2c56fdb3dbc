"""A full smoke-experiment run, shared by the workflow tests (one per test session).

The run is killed part-way (SIGKILL of the whole process group, like a lost machine), then
resumed; the resumed run must finish and must not redo jobs that had finished.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def snakemake(workdir: Path, *args: str, overrides: list[str] | None = None, check: bool = True) -> subprocess.CompletedProcess:
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(workdir), *args, "--config", "experiment=smoke"]
    if overrides:
        cmd.append("overrides=[" + ",".join(overrides) + "]")
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return proc


def planned_jobs(output: str) -> list[tuple[str, dict]]:
    """(rule, wildcards) of every job a dry run plans (the `all` target excluded)."""
    jobs = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", output):
        m = re.match(r"(?:local)?rule (\w+):", block.strip())
        if not m or m.group(1) == "all":
            continue
        wc = re.search(r"wildcards: (.*)", block)
        wildcards = dict(kv.split("=", 1) for kv in wc.group(1).split(", ")) if wc else {}
        jobs.append((m.group(1), wildcards))
    return jobs


def finished_rules(log_text: str) -> list[str]:
    return re.findall(r"Finished jobid: \d+ \(Rule: (\w+)\)", log_text)


@dataclass
class SmokeRun:
    workdir: Path
    killed_after: list[str]  # rules that had finished when the run was killed
    resumed_output: str  # snakemake's output of the resumed run
    wall_s: float


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory) -> SmokeRun:
    workdir = tmp_path_factory.mktemp("smoke")
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(workdir), "-j", "2", "--config", "experiment=smoke"]
    start = time.monotonic()
    log_path = workdir.parent / "first_run.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        # Kill once a training job is under way (the longest stage), i.e. mid-DAG.
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and proc.poll() is None:
            if list((workdir / "logs" / "train").glob("*/*.log")):
                time.sleep(3)
                break
            time.sleep(1)
        assert proc.poll() is None, f"the run ended before it could be interrupted:\n{log_path.read_text()[-3000:]}"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    killed_after = finished_rules(log_path.read_text())
    # A hard kill leaves Snakemake's lock behind; unlocking is the documented first step.
    snakemake(workdir, "--unlock")
    resumed = snakemake(workdir, "-j", "2")
    return SmokeRun(workdir, killed_after, resumed.stdout + resumed.stderr, time.monotonic() - start)

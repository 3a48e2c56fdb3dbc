"""A full smoke-experiment run, shared by the workflow tests (one per test session).

The run is killed twice at points the fixture controls (SIGKILL of the whole process group, like
a lost machine), then resumed with the plain command; it must finish and must not redo jobs whose
end Snakemake had recorded.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import psutil
import pytest
from filelock import FileLock

REPO = Path(__file__).resolve().parents[2]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def shown_pages() -> dict[Path, str]:
    """The text of every page a user reads commands from: README.md and the docs site's pages."""
    pages = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    return {page: page.read_text() for page in pages}


def readme_command(command: str) -> str:
    """`command` exactly as the README or a docs page shows it: a line of a code block
    (continuation lines joined, a trailing `# comment` aside) or an inline code span; the test
    fails when no page shows it."""
    shown = set()
    for text in shown_pages().values():
        blocks = re.findall(r"^```[a-z]*\n(.*?)^```", text, re.S | re.M)
        lines = [re.sub(r"\s+#\s.*$", "", line) for block in blocks for line in block.replace("\\\n", " ").splitlines()]
        spans = re.findall(r"`([^`\n]+)`", re.sub(r"^```.*?^```", "", text, flags=re.S | re.M))
        shown |= {" ".join(line.split()) for line in [*lines, *spans]}
    assert " ".join(command.split()) in shown, f"the README and docs/ show no command {command!r}"
    return command


def readme_block_after(command: str) -> str:
    """The code block shown right after the block that holds `command` (its output), on the
    first page (README, then the docs pages) that shows the command."""
    text = next(text for text in shown_pages().values() if command in text)
    at = text.index(command)
    start = text.index("```", text.index("```", at) + 3)
    body = text[text.index("\n", start) + 1:]
    return body[: body.index("```")]


def clone_checkout(dest: Path) -> Path:
    """A git clone of this checkout whose working tree is the checkout's as it stands (changes
    not yet committed included): what a user gets from `git clone`. CI's own checkout is a
    clean clone, so there the two are the same."""
    subprocess.run(["git", "clone", "-q", str(REPO), str(dest)], check=True)
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                            check=True, capture_output=True).stdout.decode().split("\0")
    for rel in filter(None, listed):
        source, target = REPO / rel, dest / rel
        if source.is_file():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
        elif target.exists():  # deleted in the checkout, not yet committed
            target.unlink()
    return dest


def run_as_written(command: str, cwd: Path) -> subprocess.CompletedProcess:
    """Run a command the README or the docs show through bash in `cwd`, with this interpreter's
    environment first on PATH (as after `. .venv/bin/activate`)."""
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    return subprocess.run(["bash", "-c", command], cwd=cwd, env=env, capture_output=True, text=True)


def copy_run(run: Path, dest: Path) -> None:
    """A finished run's artefacts and Snakemake's records of them, mtimes kept, into `dest`."""
    for part in ("results", "reports", "logs", ".snakemake/metadata"):
        if (run / part).exists():
            shutil.copytree(run / part, dest / part, symlinks=True, dirs_exist_ok=True)


def overrides_arg(overrides: list[str]) -> str:
    # Each override quoted: Snakemake reads the list as YAML, and a Hydra dict has commas.
    return "overrides=[" + ",".join(json.dumps(o) for o in overrides) + "]"


def snakemake(workdir: Path, *args: str, overrides: list[str] | None = None, check: bool = True) -> subprocess.CompletedProcess:
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(workdir), *args, "--config", "experiment=smoke"]
    if overrides:
        cmd.append(overrides_arg(overrides))
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return proc


def planned_job_blocks(output: str) -> list[tuple[str, dict, str]]:
    """(rule, wildcards, the dry run's text of the job) of every job a dry run plans (the `all`
    target excluded)."""
    jobs = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", output):
        m = re.match(r"(?:local)?rule (\w+):", block.strip())
        if not m or m.group(1) == "all":
            continue
        wc = re.search(r"wildcards: (.*)", block)
        wildcards = dict(kv.split("=", 1) for kv in wc.group(1).split(", ")) if wc else {}
        jobs.append((m.group(1), wildcards, block))
    return jobs


def planned_jobs(output: str) -> list[tuple[str, dict]]:
    """(rule, wildcards) of every job a dry run plans (the `all` target excluded)."""
    return [(rule, wildcards) for rule, wildcards, _ in planned_job_blocks(output)]


def finished_rules(log_text: str) -> list[str]:
    return re.findall(r"Finished jobid: \d+ \(Rule: (\w+)\)", log_text)


def _parquet_contents(results: Path) -> dict[str, pd.DataFrame]:
    """Every parquet table under results/ (lerobot datasets included), timing columns aside."""
    out = {}
    for path in sorted(results.rglob("*.parquet")):
        rel = path.relative_to(results)
        if any(part.startswith(".") for part in rel.parts):
            continue
        df = pd.read_parquet(path)
        out[str(rel)] = df.drop(columns=[c for c in df.columns if c == "wall_s" or c.endswith("_wall_s")])
    return out


def _report_files(reports: Path) -> list[Path]:
    # What the pipeline writes (other tests add DVC pointer files beside them).
    return sorted(p.relative_to(reports) for p in reports.rglob("*")
                  if p.is_file() and p.suffix != ".dvc" and not p.name.startswith("."))


def assert_same_outputs(reference: Path, other: Path, part: bool = False) -> None:
    """`other`'s run wrote the same bytes as `reference`'s: every report it has is identical, and
    every parquet table under results/ has the same contents (timing columns aside). ``part``:
    `other` ran part of `reference`'s targets, so its tables are a subset of the reference's."""
    reports = _report_files(other / "reports")
    assert reports and set(reports) <= set(_report_files(reference / "reports"))
    differ = [str(r) for r in reports if (reference / "reports" / r).read_bytes() != (other / "reports" / r).read_bytes()]
    assert differ == [], f"reports differ between the two runs: {differ}"
    first_tables, second_tables = _parquet_contents(reference / "results"), _parquet_contents(other / "results")
    if part:
        assert second_tables and set(second_tables) <= set(first_tables), sorted(set(second_tables) - set(first_tables))
    else:
        assert sorted(first_tables) == sorted(second_tables)
    for name, df in second_tables.items():
        pd.testing.assert_frame_equal(first_tables[name], df, check_exact=True, obj=name)


@dataclass
class SmokeRun:
    workdir: Path
    killed_after: list[list[str]]  # per kill: rules whose end Snakemake had recorded by then
    resumed_output: str  # snakemake's output of the last, uninterrupted run
    wall_s: float
    ingest_outputs_at_kill: list[str]  # ingest's outputs on disk when the first run was killed
    first_resume_output: str = ""


def _stage_processes(leader: int, stage: str) -> list[psutil.Process]:
    """Running (not zombie) processes of `python -m r2s_eval.stages.<stage>` under `leader`."""
    found = []
    for proc in psutil.Process(leader).children(recursive=True):
        try:
            if proc.status() != psutil.STATUS_ZOMBIE and f"r2s_eval.stages.{stage}" in " ".join(proc.cmdline()):
                found.append(proc)
        except psutil.NoSuchProcess:
            continue
    return found


def _wait_for_stage(proc: subprocess.Popen, stage: str, log_path: Path, timeout_s: float = 900) -> list[psutil.Process]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the run ended before {stage} started:\n{log_path.read_text()[-3000:]}"
        found = _stage_processes(proc.pid, stage)
        if found:
            return found
        time.sleep(0.2)
    raise AssertionError(f"{stage} did not start within {timeout_s} s")


def kill_after_job_exits(cmd: list[str], stage: str, log_path: Path) -> None:
    """Kill the run between jobs: `stage` has written its outputs and exited, Snakemake has not
    yet recorded it (Snakemake is frozen first, so it cannot start the next job either)."""
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        job = _wait_for_stage(proc, stage, log_path)[0]
        os.kill(proc.pid, signal.SIGSTOP)
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and _stage_processes(proc.pid, stage):
            time.sleep(0.2)
        assert not job.is_running() or job.status() == psutil.STATUS_ZOMBIE, f"{stage} did not finish"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def kill_inside_job(cmd: list[str], stage: str, log_path: Path, after_rule: str) -> None:
    """Kill the run while a `stage` job is running (frozen first, so it cannot finish meanwhile),
    once Snakemake has recorded that `after_rule` finished."""
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + 900
        while after_rule not in finished_rules(log_path.read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, log_path.read_text()[-3000:]
            time.sleep(0.2)
        for job in _wait_for_stage(proc, stage, log_path):
            job.suspend()
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _make_smoke_run(workdir: Path) -> SmokeRun:
    """The smoke experiment in `workdir`, killed twice like a lost machine and resumed with the
    plain command.

    First kill: one job at a time, right after ingest wrote its outputs but before Snakemake
    recorded the job (the resume must redo it, not stop on incomplete files). Second kill: inside
    a training job. A hard kill leaves Snakemake's lock behind; `--unlock` is the documented step.
    """
    workdir.mkdir(parents=True)
    base = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "-d", str(workdir)]
    start = time.monotonic()
    first_log = workdir.parent / "first_run.log"
    kill_after_job_exits([*base, "-j", "1", "--config", "experiment=smoke"], "ingest", first_log)
    ingest_outputs = sorted(p.name for p in (workdir / "results" / "ingest").iterdir())
    killed_after = [finished_rules(first_log.read_text())]
    snakemake(workdir, "--unlock")

    second_log = workdir.parent / "second_run.log"
    kill_inside_job([*base, "-j", "2", "--config", "experiment=smoke"], "train", second_log, after_rule="ingest")
    second_text = second_log.read_text()
    killed_after.append(finished_rules(second_text))
    snakemake(workdir, "--unlock")
    resumed = snakemake(workdir, "-j", "2")
    return SmokeRun(
        workdir, killed_after, resumed.stdout + resumed.stderr, time.monotonic() - start,
        ingest_outputs, second_text,
    )


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory, worker_id) -> SmokeRun:
    """One smoke run for the whole test session (`_make_smoke_run`). Under pytest-xdist the
    workers share it: the first to ask makes it while the others wait on a file lock, then read
    what it recorded; a run that failed fails their tests too, without being made again."""
    base = tmp_path_factory.getbasetemp()
    shared = base if worker_id == "master" else base.parent  # xdist: the session's folder above the workers'
    record, failed = shared / "smoke_run.json", shared / "smoke_run.failed"
    with FileLock(shared / "smoke_run.lock"):
        if failed.exists():
            pytest.fail(f"the shared smoke run failed (in another worker):\n{failed.read_text()[-3000:]}")
        if not record.exists():
            try:
                run = _make_smoke_run(shared / "smoke")
            except BaseException as error:
                failed.write_text(f"{type(error).__name__}: {error}")
                raise
            record.write_text(json.dumps({**dataclasses.asdict(run), "workdir": str(run.workdir)}))
        fields = json.loads(record.read_text())
    return SmokeRun(**{**fields, "workdir": Path(fields["workdir"])})

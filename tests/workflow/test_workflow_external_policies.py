"""Candidates that are not trained here: a checkpoint folder and a policy server, in the smoke DAG.

The smoke run's own trained checkpoints stand in for a lab's: one is copied to a folder and
entered as `type: checkpoint`, another is served by `python -m r2s_eval.serve` and entered as
`type: server`. The server is killed while its rollouts run; after a restart the rerun finishes
without redoing the episodes that had finished.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from .conftest import overrides_arg, planned_jobs, snakemake

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start_server(checkpoint: Path, port: int, log: Path) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-m", "r2s_eval.serve", str(checkpoint), "--port", str(port), "--name", "act_served"],
        stdout=open(log, "a"), stderr=subprocess.STDOUT, start_new_session=True,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()[-2000:]
        if "serving" in log.read_text():
            return proc
        time.sleep(0.2)
    raise AssertionError(f"server did not start:\n{log.read_text()[-2000:]}")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _finished_episodes(store: Path) -> int:
    return len(list(store.glob("*/row.json"))) if store.exists() else 0


def test_checkpoint_and_server_candidates_run_to_the_table(smoke_run, tmp_path):
    # A copy of the finished smoke run (times kept, so Snakemake sees it as up to date): the other
    # workflow tests need the shared run as it was.
    wd = tmp_path / "smoke"
    shutil.copytree(smoke_run.workdir, wd, symlinks=True, ignore=shutil.ignore_patterns("locks"))
    ckpt = tmp_path / "lab_checkpoint"
    shutil.copytree(wd / "results" / "train" / "real" / "act" / "pretrained_model", ckpt)
    port = _free_port()
    overrides = [
        f"+policies.act_ckpt={{type:checkpoint,path:'{ckpt}'}}",
        f"+policies.act_served={{type:server,port:{port},reply_timeout_s:30}}",
    ]
    plan = snakemake(wd, "-n", overrides=overrides).stdout
    jobs = planned_jobs(plan)
    assert not any(rule == "train" for rule, _ in jobs), "checkpoint and server candidates are never trained"
    assert {(wc["arm"], wc["policy"]) for rule, wc in jobs if rule == "rollout"} == {
        (arm, p) for arm in ("real", "sim") for p in ("act_ckpt", "act_served")
    }

    server_log = tmp_path / "server.log"
    server = _start_server(wd / "results" / "train" / "sim" / "act_subset", port, server_log)
    store = wd / "results" / "rollout" / "sim" / ".act_served.episodes"
    # One episode at a time (batch_episodes changes no result, so the rerun below may batch): side
    # by side, episodes that all run to max_steps end within milliseconds of each other, and the
    # whole set could be finished and collected before the server is killed.
    one_at_a_time = overrides_arg([*overrides, "rollout.batch_episodes=1"])
    cmd = [sys.executable, "-m", "snakemake", "-s", str(Path(__file__).resolve().parents[2] / "Snakefile"),
           "-d", str(wd), "-j", "1", "--config", "experiment=smoke", one_at_a_time]
    try:
        # One job at a time; kill the server once its sim rollouts have finished an episode.
        run = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 600
        while _finished_episodes(store) < 1:
            assert run.poll() is None and time.monotonic() < deadline, run.stdout.read()[-3000:]
            time.sleep(0.1)
        _stop(server)
        out, _ = run.communicate(timeout=600)
        assert run.returncode != 0, "the run should fail while the server is down"
        log = (wd / "logs" / "rollout" / "sim" / "act_served.log").read_text()
        assert "act_served" in log and f"127.0.0.1:{port}" in log, log[-2000:]
        kept = _finished_episodes(store)
        assert 1 <= kept < 6, f"{kept} finished episodes kept after the server died"

        server = _start_server(wd / "results" / "train" / "sim" / "act_subset", port, server_log)
        snakemake(wd, "-j", "2", overrides=overrides)
    finally:
        _stop(server)

    # The rerun ran only the episodes that had not finished before the server died.
    log = (wd / "logs" / "rollout" / "sim" / "act_served.log").read_text()
    assert len(re.findall(r"init \d+: (?:success|failure)", log)) == 6 - kept, log[-2000:]
    for arm in ("real", "sim"):
        for policy in ("act_ckpt", "act_served"):
            episodes = pd.read_parquet(wd / "results" / "rollout" / arm / policy / "episodes.parquet")
            assert len(episodes) == 6 and episodes["init_id"].is_unique
    assert not store.exists(), "finished episodes are folded into the rollout folder"
    reference = pd.read_parquet(wd / "results" / "reference" / "success.parquet")
    assert {"act_ckpt", "act_served"} <= set(reference["policy"])
    ranking = (wd / "reports" / "ranking.txt").read_text()
    assert "act_ckpt" in ranking and "act_served" in ranking

    # Same checkpoint content elsewhere, or the server on another port: nothing to redo.
    moved = tmp_path / "moved_checkpoint"
    shutil.copytree(ckpt, moved)
    other_port = _free_port()
    moved_overrides = [
        f"+policies.act_ckpt={{type:checkpoint,path:'{moved}'}}",
        f"+policies.act_served={{type:server,port:{other_port},reply_timeout_s:30}}",
    ]
    assert planned_jobs(snakemake(wd, "-n", overrides=moved_overrides).stdout) == []
    # Changed content: that candidate's rollouts rerun.
    (moved / "config.json").write_text((moved / "config.json").read_text() + "\n")
    replanned = {(rule, wc.get("policy")) for rule, wc in planned_jobs(snakemake(wd, "-n", overrides=moved_overrides).stdout)}
    assert ("rollout", "act_ckpt") in replanned and ("rollout", "act_served") not in replanned

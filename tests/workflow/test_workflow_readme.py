"""The commands the README and the docs pages show, run as written in a git clone of the checkout.

The fast ones plan only (seconds); the DVC round trip and the world report read a finished smoke
run, copied into the clone (`-m slow`, sharing the workflow tests' smoke run).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import pandas as pd
import pytest

from .conftest import (
    REPO,
    clone_checkout,
    copy_run,
    finished_rules,
    planned_jobs,
    readme_block_after,
    readme_command,
    run_as_written,
    shown_pages,
)

LAB_DATASET = ("snakemake -j 2 reports/realsim_table.tex --config "
               "overrides='[real=dataset,real.dataset_root=/data/my_teleop,real.reference_csv=/data/trials.csv]'")
BAD_OVERRIDES = ("snakemake -j 2 reports/realsim_table.tex --config "
                 "overrides='[stats.nboot=500,policies.act.steps=abc,rollout.horizon.chunk=0]'")
PUSH, PULL = "python -m r2s_eval.artifacts push", "python -m r2s_eval.artifacts pull"
WORLD_REPORT = "python -m r2s_eval.stages.world_report"
CALIBRATED_LOOK = ("python -m r2s_eval.world tabletop --experiment smoke --dataset results/real/dataset "
                   "--world-params results/calib/world_params.json")
PLAN_SMOKE = "snakemake -n --config experiment=smoke"
PANDA_PREVIEW = "python -m r2s_eval.world panda"
ADAPTIVE_SMOKE = "snakemake -j 2 reports/realsim_table.tex --config experiment=smoke overrides='[compare.allocation=adaptive]'"
PANDA_DATASET = ("snakemake -j 2 reports/realsim_table.tex --config overrides='[world=panda,suite=world,"
                 "\"tasks=[block_on_plate]\",real=dataset,real.dataset_root=/data/my_teleop,"
                 "real.reference_csv=/data/trials.csv]'")


@pytest.fixture
def clone(tmp_path) -> Path:
    return clone_checkout(tmp_path / "r2s-eval")


def _no_traceback(out: str) -> None:
    assert "Traceback" not in out and not re.search(r'^\s*File "', out, re.M), out[-3000:]


def test_bad_overrides_are_listed_one_line_each_before_anything_runs(clone):
    proc = run_as_written(readme_command(BAD_OVERRIDES), clone)
    assert proc.returncode == 1
    _no_traceback(proc.stdout + proc.stderr)
    assert proc.stderr == readme_block_after(BAD_OVERRIDES), "the README shows what the command prints"
    assert proc.stdout == "" and not (clone / "results" / "ingest").exists() and not (clone / "logs").exists()


def test_a_lab_dataset_that_is_not_there_stops_before_anything_runs(clone):
    if Path("/data/my_teleop").exists() or Path("/data/trials.csv").exists():
        pytest.skip("this machine has the example paths of docs/your-setup.md")
    proc = run_as_written(readme_command(LAB_DATASET), clone)
    assert proc.returncode == 1
    _no_traceback(proc.stdout + proc.stderr)
    assert proc.stderr.splitlines() == [
        "2 configuration problems:",
        "  - real.dataset_root = /data/my_teleop: no such folder (a LeRobotDataset v3 folder)",
        "  - real.reference_csv = /data/trials.csv: no such file (a CSV of hardware trials: policy, task, trials, "
        "successes)",
    ]


def test_the_panda_world_is_looked_at_then_pointed_at_a_lab_dataset(clone):
    pytest.importorskip("gym_hil", reason="the Panda world's robot comes from gym-hil")
    import cv2

    proc = run_as_written(readme_command(PANDA_PREVIEW), clone)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "wrote reports/world_preview/starts.png" in proc.stdout
    starts = cv2.imread(str(clone / "reports" / "world_preview" / "starts.png"))
    assert starts.shape[1] == 3 * 320  # its three recorded cameras, 320 px panels, one task
    if Path("/data/my_teleop").exists() or Path("/data/trials.csv").exists():
        pytest.skip("this machine has the example paths of docs/your-setup.md")
    proc = run_as_written(readme_command(PANDA_DATASET), clone)
    assert proc.returncode == 1
    _no_traceback(proc.stdout + proc.stderr)
    assert proc.stderr.splitlines()[0] == "2 configuration problems:", proc.stderr


def test_the_readme_shows_a_wrong_world_as_the_check_prints_it(tmp_path):
    from r2s_eval.config import compose_config
    from r2s_eval.errors import ConfigError

    shown = readme_block_after("python -m r2s_eval.world panda").strip()  # the world check's example line
    conf = Path(shutil.copytree(REPO / "conf", tmp_path / "conf"))
    world = conf / "world" / "tabletop.yaml"
    world.write_text(world.read_text().replace("joints: [j1, j2, j3, j4, j5, j6]", "joints: [j1, j2, j3, j4, j5, j7]", 1))
    with pytest.raises(ConfigError) as err:
        compose_config(conf, "smoke")
    assert str(err.value) == shown


def test_side_by_side_working_directories_stay_out_of_git(clone):
    (clone / "runs" / "smoke" / "results").mkdir(parents=True)
    (clone / "runs" / "smoke" / "results" / "x.parquet").write_bytes(b"")
    status = subprocess.run(["git", "status", "--porcelain"], cwd=clone, capture_output=True, text=True, check=True)
    assert "runs" not in status.stdout


def test_the_world_report_outside_a_run_says_where_it_comes_from(clone):
    proc = run_as_written(WORLD_REPORT, clone)
    assert proc.returncode == 1
    assert proc.stderr == ("world_report failed: results/world/report.json: no world report here; the workflow "
                           "writes it (snakemake -j 2 results/world/report.json) in the run's working directory\n")


def test_the_rollout_benchmark_renders_without_mujoco_gl(clone):
    # docs/policies.md runs it as `python benchmarks/bench_rollout_batch.py`; here two short episodes.
    readme_command("python benchmarks/bench_rollout_batch.py")
    env_less = "env -u MUJOCO_GL python benchmarks/bench_rollout_batch.py --episodes 2 --batch 2 --cameras 1 " \
               "--repeats 1 --max-steps 10"
    proc = run_as_written(env_less, clone)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert re.search(r"batched / one at a time: [\d.]+x", proc.stdout), proc.stdout


LEROBOT_EVAL = ("lerobot-eval --policy.path=results/train/sim/act/pretrained_model --policy.n_action_steps=5 "
                "--env.type=r2s_eval --env.task=cup_on_plate --env.cameras='[head_left]' "
                "--env.world_params=results/calib/world_params.json --env.inits=results/rollout/inits.parquet "
                "--env.episode_length=110 --eval.n_episodes=6 --eval.batch_size=1 --seed=0 --output_dir=outputs/eval/act_sim")


def _contents(root: Path) -> dict[str, str]:
    """Every file under results/ and reports/ by its SHA-256."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for part in ("results", "reports") for p in sorted((root / part).rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_adaptive_allocation_judges_the_smoke_rollouts_again(smoke_run, clone):
    # The adaptive command of docs/judges.md on a finished smoke run: only the comparison plan, the
    # judging and what follows rerun; each (task, init) is compared once per pair, a two-step
    # judge describes only what it compared, the ranking says what was decided, and a second
    # call plans nothing.
    copy_run(smoke_run.workdir, clone)
    proc = run_as_written(readme_command(ADAPTIVE_SMOKE), clone)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ran = finished_rules(proc.stdout + proc.stderr)
    assert "compare_pairs" in ran and "judge_adaptive_described" in ran, ran
    assert not set(ran) & {"train", "rollout", "describe", "descriptions", "judge_pairs", "teleop", "replay"}, ran
    for judge in ("kinematic", "video"):
        folder = clone / "results" / "judge" / judge
        verdicts = pd.read_parquet(folder / "verdicts.parquet")
        assert verdicts["sequence_index"].tolist() == list(range(len(verdicts)))
        for _, g in verdicts.groupby(["policy_i", "policy_j"]):
            assert len(set(zip(g["task"], g["init_id"]))) == len(g)  # no (task, init) twice in a pair
        described = pd.read_parquet(folder / "descriptions.parquet")
        assert set(described["episode_id"]) == set(verdicts["episode_a"]) | set(verdicts["episode_b"])
        stats = json.loads((folder / "compare_stats.json").read_text())
        made = json.loads((folder / "describe_stats.json").read_text())
        assert stats["allocation"] == "adaptive" and stats["describe_calls"] == made["calls"]
        assert made["calls"] + made["cache_hits"] == len(described)  # the copy kept the answer cache
    ranking = (clone / "reports" / "ranking.txt").read_text()
    assert "kinematic: adaptive judging stopped" in ranking and "video: adaptive judging stopped" in ranking
    again = run_as_written(ADAPTIVE_SMOKE.replace("-j 2", "-n"), clone)
    assert planned_jobs(again.stdout) == [], again.stdout[-2000:]


@pytest.mark.slow
def test_dvc_push_and_pull_round_trip_in_a_clone(smoke_run, clone):
    copy_run(smoke_run.workdir, clone)
    assert (clone / "reports" / "browser").is_dir(), "a run with every report built"
    assert planned_jobs(run_as_written(PLAN_SMOKE, clone).stdout) == []

    # A DVC command that fails is one paragraph naming it and DVC's message.
    failed = run_as_written(f"{PUSH} --remote nosuch", clone)
    assert failed.returncode == 1
    _no_traceback(failed.stderr)
    assert re.fullmatch(r"artifacts failed: `dvc push --remote nosuch <\d+ paths>` failed in \S+ \(exit status \d+\): "
                        r".*nosuch.*\n", failed.stderr), failed.stderr

    pushed = run_as_written(readme_command(PUSH), clone)
    assert pushed.returncode == 0, pushed.stderr[-3000:]
    assert "tracked reports/browser" in pushed.stdout and "tracked results/real/dataset" in pushed.stdout
    # What docs/artefacts.md says to commit is not ignored by git.
    untracked = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=clone,
                               capture_output=True, text=True, check=True).stdout
    pointers = {line[3:] for line in untracked.splitlines() if line.startswith("?? ")}
    for path in ["reports/realsim_table.tex.dvc", "reports/browser.dvc", "reports/index.html.dvc",
                 "results/real/dataset.dvc", "results/train/real/act.dvc", "artifacts.mtimes.json"]:
        assert path in pointers, (path, sorted(pointers))
    assert not any(p.startswith(("results/", "reports/")) and not p.endswith((".dvc", ".gitignore")) for p in pointers)

    before = _contents(clone)
    shutil.rmtree(clone / "results" / "real" / "dataset")
    shutil.rmtree(clone / "results" / "train" / "real" / "act")
    shutil.rmtree(clone / "reports" / "browser")
    (clone / "reports" / "realsim_table.tex").unlink()
    pulled = run_as_written(readme_command(PULL), clone)
    assert pulled.returncode == 0, pulled.stderr[-3000:]
    assert _contents(clone) == before, "pull restores what was missing and deletes nothing"
    assert planned_jobs(run_as_written(PLAN_SMOKE, clone).stdout) == []

    # A pull with nothing missing changes nothing either.
    assert run_as_written(PULL, clone).returncode == 0
    assert _contents(clone) == before
    assert planned_jobs(run_as_written(PLAN_SMOKE, clone).stdout) == []


@pytest.mark.slow
def test_readme_commands_in_a_finished_run(smoke_run, clone):
    copy_run(smoke_run.workdir, clone)
    before = _contents(clone)
    # A lab's dataset that is not there: the twin's reports must not pass as the lab's result.
    if not Path("/data/my_teleop").exists():
        proc = run_as_written(readme_command(LAB_DATASET), clone)
        assert proc.returncode == 1 and "real.dataset_root = /data/my_teleop: no such folder" in proc.stderr
        assert "Nothing to be done" not in proc.stdout + proc.stderr
        assert _contents(clone) == before
    # The world report, printed in the run's working directory.
    shown = run_as_written(readme_command(WORLD_REPORT), clone)
    assert shown.returncode == 0, shown.stderr
    header, rule, *rows = shown.stdout.splitlines()
    assert header.split()[:2] == ["task", "object"] and set(rule) == {"-"}
    assert any(row.startswith("cup_on_plate") for row in rows), shown.stdout
    assert "camera pose error against the twin" in shown.stdout and "the calibrated sim uses: board" in shown.stdout
    # The recording through the calibrated sim's cameras, the simulation outlined on it.
    look = run_as_written(readme_command(CALIBRATED_LOOK), clone)
    assert look.returncode == 0, look.stderr
    assert f"wrote {Path('reports/world_preview/dataset.png')}" in look.stdout
    assert cv2.imread(str(clone / "reports" / "world_preview" / "dataset.png")) is not None
    # LeRobot's own lerobot-eval on the calibrated sim (docs/lerobot.md), with the `act` the run
    # trained on sim data, from the rollout stage's inits and episode seeds: the rollout stage's
    # success, episode for episode (the two ask the model on 1 and 32 rows: they may part only
    # where a rounding of 1e-8 decides an episode, which it did in none of 30 measured).
    evaluated = run_as_written(readme_command(LEROBOT_EVAL), clone)
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    metrics = json.loads((clone / "outputs" / "eval" / "act_sim" / "eval_info.json").read_text())["per_task"][0]["metrics"]
    stage = pd.read_parquet(clone / "results" / "rollout" / "sim" / "act" / "episodes.parquet")
    stage = stage[stage["task"] == "cup_on_plate"].sort_values("init_id")
    assert metrics["successes"] == stage["success"].astype(bool).tolist(), (metrics["successes"], stage["success"].tolist())
    assert len(metrics["video_paths"]) == len(stage) and all((clone / v).is_file() for v in metrics["video_paths"])
    # The page's Gymnasium example, as written, on the same calibrated sim.
    page = (REPO / "docs" / "lerobot.md").read_text()
    example = re.search(r"^```python\n(.*?)^```", page[page.index("## In Gymnasium"):], re.S | re.M).group(1)
    (clone / "gym_example.py").write_text(example + "assert frame.ndim == 3 and obs['agent_pos'].shape == (14,)\n")
    ran = run_as_written("python gym_example.py", clone)
    assert ran.returncode == 0, ran.stderr[-3000:]


def test_readme_helpers_read_the_readme_as_written():
    # readme_command joins continuation lines and drops trailing comments, nothing else.
    assert readme_command(LAB_DATASET) == LAB_DATASET
    with pytest.raises(AssertionError, match="show no command"):
        readme_command(LAB_DATASET.replace("-j 2", "-j 3"))


NEW_TASK_COMMAND = next(line for text in shown_pages().values() for line in text.splitlines()
                        if line.startswith("snakemake -j 2 reports/realsim_table.tex --config experiment=smoke "
                                           "overrides='[\"+world.tasks.ball_on_plate="))


@pytest.mark.slow
@pytest.mark.by_hand  # a whole smoke run of its own (docs/tests.md: what CI leaves to be run by hand)
def test_a_task_added_by_config_alone_runs_through_the_smoke_chain(clone):
    # An eighth task, defined on the command line (objects already in the world, a success made
    # of predicates, an operator plan): recorded, calibrated, replayed, trained on, rolled out and
    # judged, to the report.
    proc = run_as_written(readme_command(NEW_TASK_COMMAND), clone)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = clone / "results"
    index = pd.read_parquet(results / "ingest" / "episodes.parquet")
    assert set(index["task"]) == {"ball_on_plate"} and set(index["instruction"]) == {"Put the Ball on the Plate"}
    estimates = pd.read_parquet(results / "init" / "estimates.parquet")
    assert set(estimates["object"]) == {"ball", "plate"}
    assert pd.read_parquet(results / "replay" / "log.parquet")["success"].mean() >= 0.75
    for arm in ("real", "sim"):
        episodes = pd.read_parquet(results / "rollout" / arm / "act" / "episodes.parquet")
        assert set(episodes["task"]) == {"ball_on_plate"}
    described = pd.read_parquet(results / "judge" / "video" / "descriptions.parquet")
    progress = [json.loads(d)["criteria"]["task_progress"]["evidence"] for d in described["description"]]
    assert {(p["task"], p["relation"], p["object"], p["reference"]) for p in progress} == {
        ("ball_on_plate", "on", "ball", "plate")}
    assert (clone / "reports" / "realsim_table.tex").is_file()

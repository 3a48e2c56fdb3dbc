"""The offline video judge: reads only the video and the instruction, describes from pixels."""

from __future__ import annotations

import builtins
import io
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from r2s_eval.compare import sample_pairs
from r2s_eval.judge import CRITERIA, RolloutInput, VideoJudge, describe_rollouts, judge_pairs, make_judge
from r2s_eval.judge.video_judge import task_from_instruction


from tests.helpers.videos import SIM_TASK, render_sim_episodes
from tests.helpers.worlds import bundled_tasks

CFG = {"backend": "video"}
TASKS = bundled_tasks()


def video_judge(cfg=CFG) -> VideoJudge:
    """The video judge of ``cfg``, knowing the bundled world's tasks (as ``world_judge`` tells it a world's)."""
    judge = make_judge(cfg)
    judge.know_tasks(TASKS)
    return judge


@pytest.fixture(scope="module")
def sim_episodes(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim_episodes")
    df = render_sim_episodes(root)
    assert df["success"].tolist() == [True, False]  # the operator succeeds, the frozen policy fails
    return df, root


def _describe(judge, df, root, i):
    row = df.iloc[i]
    return judge.describe(RolloutInput(row["instruction"], video_path=root / row["video_path"]))


def test_judge_video_never_opens_trajectory_or_episode_table(sim_episodes, tmp_path, monkeypatch):
    df, root = sim_episodes
    opened: list[str] = []

    def guard(fn):
        def wrapped(path, *args, **kwargs):
            if str(getattr(path, "path", path)).endswith(".parquet"):
                opened.append(str(path))
                raise AssertionError(f"video judging opened {path}")
            return fn(path, *args, **kwargs)

        return wrapped

    for mod, attr in ((builtins, "open"), (io, "open"), (pd, "read_parquet"), (pq, "read_table"),
                      (pq, "ParquetFile"), (pq, "read_pandas")):
        monkeypatch.setattr(mod, attr, guard(getattr(mod, attr)))
    judge = video_judge()
    desc = describe_rollouts(df, root, judge, tmp_path / "cache")
    pairs = sample_pairs(df, ["ScriptedOperator", "FrozenPolicy"], [4], seed=0)
    judged = judge_pairs(pairs, desc, judge, tmp_path / "cache")
    assert not opened
    assert (desc["missing"] == "").all()
    assert desc["progress_label"].tolist() == ["successful", "failed"]
    assert (judged["winner"] == "ScriptedOperator").all()
    # The guard works: the trajectory-reading kinematic judge trips it.
    with pytest.raises(Exception, match=r"opened .*\.parquet"):
        describe_rollouts(df, root, make_judge({"backend": "kinematic"}), tmp_path / "cache2")
    assert opened


def test_judge_video_operator_beats_frozen_policy_in_both_orders(sim_episodes):
    df, root = sim_episodes
    judge = video_judge()
    op, frozen = _describe(judge, df, root, 0), _describe(judge, df, root, 1)
    assert op.missing == () and frozen.missing == ()
    assert op.progress_label == "successful" and frozen.progress_label == "failed"
    sp, sf = judge.scores(op), judge.scores(frozen)
    assert sp["task_progress"] > sf["task_progress"]
    assert op.criteria["task_progress"].evidence["max_move"] > 1.0
    # A still scene: the cup's mask moves by no more than the encoder's quantisation jitter.
    assert frozen.criteria["task_progress"].evidence["max_move"] < 0.02
    assert frozen.criteria["action_continuity"].evidence["robot_moved"] is False
    instruction = df["instruction"].iloc[0]
    assert judge.compare(op, frozen, instruction).letter == "A"
    assert judge.compare(frozen, op, instruction).letter == "B"


def test_judge_video_descriptions_are_deterministic(sim_episodes):
    df, root = sim_episodes
    first = _describe(video_judge(), df, root, 0)
    again = _describe(video_judge(), df, root, 0)
    assert first.to_json() == again.to_json()
    assert set(first.criteria) == set(CRITERIA)
    assert "not a VLM" in first.summary


def test_judge_video_equal_weights_no_priority():
    """A failed but otherwise clean rollout can beat a successful one that is poor on the other three."""
    from r2s_eval.judge import CriterionNote, Description

    judge = VideoJudge(CFG)

    def desc(progress, label, jerk, idle, speed):
        return Description(criteria={
            "motion_smoothness": CriterionNote("m", {"energy_jerk": jerk, "energy_spike_share": 0.0}),
            "action_continuity": CriterionNote("c", {"idle_fraction": idle, "pauses_per_100_frames": 0.0}),
            "task_progress": CriterionNote("p", {"progress_score": progress}, label),
            "force_control": CriterionNote("f", {"peak_object_speed": speed, "object_speed_spikes": 0,
                                                 "bystander_move": 0.0, "object_moved": True}),
        }, summary="s", judge=judge.name)

    lucky = desc(1.0, "successful", jerk=50.0, idle=5.0, speed=50.0)
    clean = desc(0.5, "partially successful", jerk=0.0, idle=0.0, speed=0.0)
    assert judge.compare(lucky, clean, "Stack the Two Blocks").letter == "B"
    assert judge.compare(clean, lucky, "Stack the Two Blocks").letter == "A"


def test_judge_video_config_and_identity():
    with pytest.raises(ValueError, match="unknown config keys.*'diff_treshold'"):
        make_judge({"backend": "video", "diff_treshold": 5})
    with pytest.raises(ValueError, match="unknown ref keys.*'idle'"):
        make_judge({"backend": "video", "ref": {"idle": 1.0}})
    a, b = video_judge(), video_judge({"backend": "video", "near_max": 0.6})
    assert a.identity()["prompt_version"].startswith("video-")
    assert a.identity()["config_hash"] != b.identity()["config_hash"]
    assert a.inputs == ("video",)
    assert task_from_instruction("Pick the Cup and Place it on the Plate", TASKS) == SIM_TASK
    assert task_from_instruction("stack the two blocks", TASKS) == "stack_blocks"
    with pytest.raises(ValueError, match="no known task"):
        task_from_instruction("fold the towel", TASKS)


def test_judge_video_smoke_and_demo_run_both_offline_judges():
    from r2s_eval.config import compose_config

    conf = Path(__file__).resolve().parents[2] / "conf"
    for experiment in ("smoke", "demo"):
        judges = compose_config(conf, experiment=experiment)["judges"]
        assert {name: j["backend"] for name, j in judges.items()} == {"kinematic": "kinematic", "video": "video"}
        make_judge(judges["video"])  # the configured entry builds


def test_goal_relations_come_from_the_tasks_success_conditions():
    # The relation the judge looks for in the pixels is read from each task's definition (the
    # table it replaced, pinned).
    from r2s_eval.judge.video_judge import goal_relation

    assert {key: goal_relation(task) for key, task in TASKS.items()} == {
        "cup_on_plate": ("on", "cup", "plate"), "ball_in_box": ("in", "ball", "box"),
        "ball_in_cup": ("in", "ball", "cup"), "cover_ball": ("cover", "cup", "ball"),
        "stack_blocks": ("stack", "block_a", "block_b"), "block_from_box": ("out", "block_a", "box"),
        "upright_cup": ("upright", "cup", None),
    }

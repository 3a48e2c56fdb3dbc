"""The offline video judge: reads only the video and the instruction, describes from pixels."""

from __future__ import annotations

import builtins
import io
from pathlib import Path

import numpy as np
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


def _scored(judge, progress, label, reversals, idle, speed):
    """A description of the video judge's form with the given numbers."""
    from r2s_eval.judge import CriterionNote, Description

    return Description(criteria={
        "motion_smoothness": CriterionNote("m", {"flow_reversals_per_s": reversals}),
        "action_continuity": CriterionNote("c", {"idle_fraction": idle, "pauses_per_100_frames": 0.0,
                                                 "slowdowns_per_s": 0.0}),
        "task_progress": CriterionNote("p", {"progress_score": progress}, label),
        "force_control": CriterionNote("f", {"peak_object_speed": speed, "object_speed_spikes": 0,
                                             "bystander_move": 0.0, "object_moved": True}),
    }, summary="s", judge=judge.name)


def test_judge_video_success_before_style():
    """A successful rollout beats one that is not, however poor its other three criteria; the
    verdict names the rule."""
    judge = VideoJudge(CFG)
    shaky = _scored(judge, 1.0, "successful", reversals=50.0, idle=5.0, speed=50.0)
    for label, progress in (("partially successful", 0.9), ("failed", 0.1)):
        smooth = _scored(judge, progress, label, reversals=0.0, idle=0.0, speed=0.0)
        assert judge.compare(shaky, smooth, "Stack the Two Blocks").letter == "A"
        verdict = judge.compare(smooth, shaky, "Stack the Two Blocks")
        assert verdict.letter == "B" and "success before style" in verdict.rationale


def test_judge_video_two_failures_are_compared_by_progress_alone_or_a_tie():
    """Neither reached the goal: the task-progress score decides where it differs by more than
    progress_margin, not the labels and not how the runs moved, so a shaky run that got plainly
    further beats a clean one that got less far, labelled partially successful or failed; a
    smaller difference, or failures: tie, is a tie (the letter from the description hashes, the
    same run in both orders)."""
    poor_cfg = dict(reversals=50.0, idle=5.0, speed=50.0)
    clean_cfg = dict(reversals=0.0, idle=0.0, speed=0.0)
    tie = VideoJudge({**CFG, "failures": "tie"})
    poor = _scored(tie, 0.6, "partially successful", **poor_cfg)
    clean = _scored(tie, 0.15, "failed", **clean_cfg)
    first, second = tie.compare(poor, clean, "Stack the Two Blocks"), tie.compare(clean, poor, "Stack the Two Blocks")
    assert (first.letter == "A") == (second.letter == "B") == (poor.sha256() < clean.sha256())
    assert "a tie" in first.rationale

    judge = VideoJudge(CFG)
    assert judge.cfg["failures"] == "progress"
    poor = _scored(judge, 0.6, "partially successful", **poor_cfg)
    clean = _scored(judge, 0.15, "failed", **clean_cfg)
    assert judge.compare(poor, clean, "Stack the Two Blocks").letter == "A"
    verdict = judge.compare(clean, poor, "Stack the Two Blocks")
    assert verdict.letter == "B" and verdict.rationale.startswith("neither successful; task progress")
    # The labels do not rank: a run labelled failed that got plainly further wins too...
    exact = VideoJudge({**CFG, "progress_margin": 0.0})
    further = _scored(exact, 0.18, "failed", reversals=50.0, idle=5.0, speed=50.0)
    less_far = _scored(exact, 0.16, "failed", reversals=0.0, idle=0.0, speed=0.0)
    assert exact.compare(less_far, further, "Stack the Two Blocks").letter == "B"
    # ...and within the margin the difference is a tie.
    within = judge.compare(less_far, further, "Stack the Two Blocks")
    assert within.rationale.startswith("exact tie") and (within.letter == "A") == (less_far.sha256() < further.sha256())
    # Both successful: the scores decide too.
    shaky, calm = (_scored(judge, 1.0, "successful", reversals=r, idle=0.0, speed=0.1) for r in (3.0, 0.1))
    assert judge.compare(shaky, calm, "Stack the Two Blocks").letter == "B"


def test_judge_video_style_counts_beyond_its_margin_the_goal_time_always():
    """Two successes: a smoothness difference within style_margin is noise and does not outvote
    a later goal; one beyond it counts."""
    from r2s_eval.judge import CriterionNote, Description

    judge = VideoJudge(CFG)

    def success(reversals: float, reached_s: float) -> Description:
        d = _scored(judge, 1.0, "successful", reversals=reversals, idle=0.0, speed=0.1)
        d.criteria["task_progress"] = CriterionNote("p", {"progress_score": 1.0, "goal_met": True,
                                                          "goal_reached_s": reached_s}, "successful")
        return d

    smoothness = lambda r: judge.criterion_score("motion_smoothness", {"flow_reversals_per_s": r})
    prompt, slow = success(0.55, 5.0), success(0.45, 7.0)  # slightly less smooth, reached 2 s sooner
    assert 0 < smoothness(0.45) - smoothness(0.55) < judge.cfg["style_margin"]
    assert judge.compare(prompt, slow, "Stack the Two Blocks").letter == "A"
    assert judge.compare(slow, prompt, "Stack the Two Blocks").letter == "B"
    shaky = success(3.0, 5.0)  # plainly jerkier, as prompt
    assert smoothness(0.45) - smoothness(3.0) > judge.cfg["style_margin"]
    assert judge.compare(shaky, slow, "Stack the Two Blocks").letter == "B"
    # With no margin the small smoothness difference counts again (and here outweighs the goal time).
    exact = VideoJudge({**CFG, "style_margin": 0.0})
    a, b = success(1.5, 5.0), success(0.1, 5.6)
    assert exact.compare(a, b, "Stack the Two Blocks").letter == "B"


def _moving_square(side: int, shake_px: float) -> np.ndarray:
    """20 frames of a textured square (a quarter of the image wide) crossing a grey image at 0.025
    of the image per frame, its position shaken back and forth by `shake_px` (in a 128 px image's
    pixels) every frame."""
    import cv2

    texture = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (side // 4, side // 4, 3), dtype=np.uint8),
                               (0, 0), side / 128)
    frames = np.full((20, side, side, 3), 128, np.uint8)
    for t in range(20):
        x = round(side * (0.1 + 0.025 * t) + (side / 128) * shake_px * (-1) ** t)
        frames[t, side // 3: side // 3 + side // 4, x: x + side // 4] = texture
    return frames


def test_judge_video_flow_is_on_an_absolute_scale():
    from r2s_eval.judge.video_judge import cell_flow, flow_reversals_per_s, grey

    for side in (128, 256):  # the same motion at two resolutions: the same numbers
        steady = cell_flow(grey(_moving_square(side, 0.0)), 10.0, 128, 8)
        assert steady.shape == (19, 16, 16, 2)
        # The cells inside the square (rows 6-8; from its left edge 12.8 + 3.2 t px on): 0.025 of
        # the image per frame at 10 fps is 0.25 image per second.
        inside = [steady[t, 6:9, int(np.ceil((12.8 + 3.2 * t) / 8)):][:, :3, 0] for t in range(19)]
        assert np.median(np.concatenate([c.ravel() for c in inside])) == pytest.approx(0.25, rel=0.1)
        assert flow_reversals_per_s(steady, 10.0, 0.02) < 0.5
        shaken = cell_flow(grey(_moving_square(side, 3.0)), 10.0, 128, 8)
        assert flow_reversals_per_s(shaken, 10.0, 0.02) > 2.0
    # Its definition: per second of moving-cell time, slow cells left out.
    back_and_forth = np.zeros((11, 2, 2, 2))
    back_and_forth[:, 0, 0, 0] = 0.1 * (-1.0) ** np.arange(11)
    back_and_forth[:, 1, 1, 0] = 0.001 * (-1.0) ** np.arange(11)  # below the minimum speed
    assert flow_reversals_per_s(back_and_forth, 5.0, 0.02) == pytest.approx(5.0)
    assert flow_reversals_per_s(np.abs(back_and_forth), 5.0, 0.02) == 0.0
    assert flow_reversals_per_s(np.zeros((11, 2, 2, 2)), 5.0, 0.02) is None
    assert flow_reversals_per_s(cell_flow(np.zeros((5, 6, 6), np.uint8), 5.0, 128, 8), 5.0, 0.02) is None  # too small


def test_judge_video_jitter_raises_reversals_and_loses(operator_runs):
    """The same episode with jittered arm commands: more direction reversals per second and a lower
    smoothness score whatever its motion level, and the judge prefers the clean run."""
    from r2s_eval.judge.video_judge import video_fps

    judge = video_judge()
    for key in ("video_path", "video_5fps_path"):
        clean, jittery = (judge.describe(RolloutInput(operator_runs[n]["instruction"], video_path=operator_runs[n][key]))
                          for n in ("clean", "jittery"))
        ev_c, ev_j = clean.criteria["motion_smoothness"].evidence, jittery.criteria["motion_smoothness"].evidence
        assert ev_j["flow_reversals_per_s"] > 3 * ev_c["flow_reversals_per_s"], key
        assert judge.scores(jittery)["motion_smoothness"] < judge.scores(clean)["motion_smoothness"] - 0.2, key
        assert "turn back" in clean.criteria["motion_smoothness"].text
    assert video_fps(operator_runs["clean"]["video_5fps_path"]) == 5.0
    # At the rollout stage's 5 fps (the same outcome read for both) the clean run wins. At a frame
    # per control step the operator's grasp holds show as pauses, which the jitter fills with
    # motion: the continuity criterion then favours the jittered run as much as smoothness does not.
    assert clean.progress_label == jittery.progress_label
    instruction = operator_runs["clean"]["instruction"]
    assert judge.compare(clean, jittery, instruction).letter == "A"
    assert judge.compare(jittery, clean, instruction).letter == "B"


def test_judge_video_config_and_identity():
    with pytest.raises(ValueError, match="unknown config keys.*'diff_treshold'"):
        make_judge({"backend": "video", "diff_treshold": 5})
    with pytest.raises(ValueError, match="unknown ref keys.*'idle'"):
        make_judge({"backend": "video", "ref": {"idle": 1.0}})
    with pytest.raises(ValueError, match="flow_cell_px"):
        make_judge({"backend": "video", "flow_cell_px": 0})
    with pytest.raises(ValueError, match="reversal_min_speed"):
        make_judge({"backend": "video", "reversal_min_speed": 0.0})
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


def test_judge_video_reads_the_goal_over_the_last_fraction_of_a_second():
    """The end the goal is read in spans ``end_s`` seconds whatever the frame rate (a rollout
    ends 0.3 s after its success at 10 Hz: 2 frames at 5 fps, 3 at 10 fps), never no frame."""
    from r2s_eval.judge.video_judge import end_frame_count

    assert [end_frame_count(0.3, fps) for fps in (5, 10, 2, 30)] == [2, 3, 1, 9]
    assert end_frame_count(0.01, 5) == 1
    with pytest.raises(ValueError, match="end_s"):
        make_judge({"backend": "video", "end_s": 0})


def test_judge_video_prefers_the_success_that_got_there_sooner(operator_runs, tmp_path):
    """The same successful run started two seconds later (still frames before the first motion,
    outside the active span continuity is measured on): the goal holds from two seconds later,
    every other number is the same, and the judge prefers the run that got there sooner."""
    from r2s_eval.rollout.mp4 import read_video, write_video

    run = operator_runs["clean"]
    frames = read_video(run["video_5fps_path"])
    late = tmp_path / "late.mp4"
    write_video(late, np.concatenate([np.repeat(frames[:1], 10, axis=0), frames]), fps=5)
    judge = video_judge()
    soon, later = (judge.describe(RolloutInput(run["instruction"], video_path=p)) for p in (run["video_5fps_path"], late))
    assert soon.progress_label == later.progress_label == "successful"
    t_soon = soon.criteria["task_progress"].evidence["goal_reached_s"]
    t_late = later.criteria["task_progress"].evidence["goal_reached_s"]
    assert t_late == pytest.approx(t_soon + 2.0)
    assert "holds from" in soon.criteria["task_progress"].text
    assert judge.scores(soon)["task_progress"] > judge.scores(later)["task_progress"]
    assert judge.compare(soon, later, run["instruction"]).letter == "A"
    assert judge.compare(later, soon, run["instruction"]).letter == "B"


def test_judge_video_sees_short_stops_as_slowdowns(operator_runs):
    """The operator holding its command 3 control steps in every 13 (the planted act_hesitant's
    stops): at 5 fps a stop spans a frame step or two and the arm settles only partly, so few of
    them make a still frame (one pause here); the image speed dips at each, and continuity reads
    those dips."""
    judge = video_judge()
    instruction = operator_runs["clean"]["instruction"]
    clean, hesitant = (judge.describe(RolloutInput(instruction, video_path=operator_runs[n]["video_5fps_path"]))
                       for n in ("clean", "hesitant"))
    ev_c, ev_h = clean.criteria["action_continuity"].evidence, hesitant.criteria["action_continuity"].evidence
    assert operator_runs["hesitant"]["success"] and hesitant.progress_label == "successful"
    assert ev_h["slowdowns_per_s"] > 1.3 * ev_c["slowdowns_per_s"] > 0  # 0.73 and 0.47 a second
    assert judge.scores(hesitant)["action_continuity"] < judge.scores(clean)["action_continuity"]
    assert "short slowdowns per second" in clean.criteria["action_continuity"].text
    assert judge.compare(clean, hesitant, instruction).letter == "A"
    assert judge.compare(hesitant, clean, instruction).letter == "B"


def test_judge_video_slowdowns_count_dips_in_the_image_speed():
    """A dip below slowdown_ratio of the motion on both sides counts, a slowing that stays above it
    does not, nor a still scene; per second of moving time; the keys are checked."""
    from r2s_eval.judge.video_judge import DEFAULTS, slowdowns_per_s

    def flow(speeds):  # one cell moving right at each speed
        return np.array(speeds, float).reshape(-1, 1, 1, 1) * np.array([1.0, 0.0])

    fast = [0.05] * 4
    assert slowdowns_per_s(flow(fast + [0.01] + fast + [0.01] + fast), 5.0, DEFAULTS) == pytest.approx(2 * 5.0 / 14)
    assert slowdowns_per_s(flow(fast + [0.03] + fast), 5.0, DEFAULTS) == 0.0
    assert slowdowns_per_s(flow([0.0] * 9), 5.0, DEFAULTS) == 0.0
    assert slowdowns_per_s(np.zeros((0, 0, 0, 2)), 5.0, DEFAULTS) == 0.0
    for bad in ({"slowdown_ratio": 1.0}, {"slowdown_window_s": 0}, {"slowdown_floor": -1}):
        with pytest.raises(ValueError, match="slowdown"):
            make_judge({"backend": "video", **bad})

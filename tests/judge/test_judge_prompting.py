"""Prompt templates, strict reply parsing, frame sampling and the replacement reserve."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.compare.sampling import sample_pairs, sample_reserve
from r2s_eval.judge import CRITERIA, CriterionNote, Description, make_judge
from r2s_eval.judge.frames import sample_clip
from r2s_eval.judge.prompting import (
    TEMPLATES,
    description_text,
    fields,
    parse_description,
    parse_letter,
    render,
)
from r2s_eval.rollout.video import write_video


@pytest.mark.parametrize("reply,letter", [
    ("A", "A"), ("B", "B"), (" B.\n", "B"), ("**A**", "A"), ("Answer: B", "B"), ("answer: (A)", "A"),
    ('"B"', "B"), ("<think>A looks worse.</think>\nB", "B"),
    ("A or B", None), ("The answer is A", None), ("a", None), ("AB", None), ("", None),
    ("Rollout A is better", None), ("A. Because it is smoother.", None),
])
def test_judge_letter_parsing_is_strict(reply, letter):
    assert parse_letter(reply) == letter


def test_judge_description_parsing_finds_sections_and_the_label():
    reply = (
        "1. **Motion smoothness:** smooth overall.\n"
        "2. Action continuity: one short pause.\n"
        "### Task success: Partially successful. The cube was lifted but not placed.\n"
        "- Force/effort control: gentle.\n"
        "Summary: a careful but incomplete attempt."
    )
    d = parse_description(reply, judge="m")
    assert d.missing == () and d.progress_label == "partially successful" and d.raw_text == reply
    assert d.criteria["action_continuity"].text == "one short pause."
    assert d.summary == "a careful but incomplete attempt."
    assert parse_description("Task success: unsuccessful, it dropped the cube.", "m").progress_label == "failed"
    partial = parse_description("Motion smoothness: jerky.\nTask success: the cube moved.\nSummary: meh.", "m")
    # No label in the task section, two criteria absent: all flagged.
    assert partial.missing == ("action_continuity", "task_progress", "force_control")
    assert parse_description("I cannot see a robot.", "m").missing == (*CRITERIA, "summary")


def test_judge_templates_take_only_the_instruction_and_the_recordings():
    assert set(TEMPLATES) == {"system", "describe", "compare", "compare_videos", "reask"}
    assert fields("describe") == {"instruction", "n_frames", "duration_s", "video"}
    assert fields("compare") == {"instruction", "description_a", "description_b"}
    with pytest.raises(ValueError, match="takes fields"):
        render("compare", instruction="x", description_a="a", description_b="b", policy="act")
    for label in ("successful", "partially successful", "failed"):
        assert label in render("describe", instruction="x", n_frames=1, duration_s=1, video="")
    # What the compare prompt shows of a description: the sections, not who wrote it.
    d = Description(criteria={"task_progress": CriterionNote("done", label="successful")}, summary="ok",
                    judge="secret-judge-name")
    text = description_text(d)
    assert "Task success: successful. done" in text and "secret-judge-name" not in text
    assert "Motion smoothness: (not described)" in text


def test_judge_frames_sampled_at_rate_within_budget(tmp_path):
    frames = [np.full((32, 48, 3), 4 * i, np.uint8) for i in range(60)]  # 3 s at 20 fps
    write_video(tmp_path / "v.mp4", frames, fps=20)
    clip = sample_clip(tmp_path / "v.mp4", fps=10, max_frames=64)
    assert len(clip.frames) == 30 and np.allclose(np.diff(clip.times_s), 0.1) and clip.duration_s == pytest.approx(3.0)
    sub = sample_clip(tmp_path / "v.mp4", fps=10, max_frames=8)
    assert len(sub.frames) == 8 and sub.times_s[0] == 0 and sub.times_s[-1] == pytest.approx(2.9)
    cut = sample_clip(tmp_path / "v.mp4", fps=10, max_frames=8, over_budget="truncate")
    assert cut.times_s[-1] == pytest.approx(0.7) and cut.duration_s == pytest.approx(0.8)
    small = sample_clip(tmp_path / "v.mp4", fps=10, max_frames=8, max_side_px=24)
    assert small.frames.shape[1:] == (16, 24, 3)
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    with pytest.raises(ValueError, match="bad.mp4"):
        sample_clip(tmp_path / "bad.mp4")


def test_judge_stage_options_stay_out_of_the_cache_identity():
    base = {"backend": "openai", "model": "m", "base_url": "http://a/v1"}
    a = make_judge(base)
    b = make_judge({**base, "base_url": "http://b/v1", "concurrency": 8, "swap_share": 1.0, "name": "other"})
    assert a.identity() == b.identity() and b.stage_cfg["concurrency"] == 8
    assert make_judge({**base, "max_frames": 16}).identity() != a.identity()
    assert make_judge({"backend": "kinematic", "swap_share": 0.5}).stage_cfg["swap_share"] == 0.5
    with pytest.raises(ValueError, match="mode must be one of"):
        make_judge({**base, "mode": "three_step"})


def test_judge_reserve_continues_the_seeded_pair_sequences(episode_table, tmp_path):
    specs = [{"policy": p, "task": t, "init_id": i} for p in ("P1", "P2", "P3") for t in ("lift", "stack")
             for i in range(3)]
    episodes = episode_table(tmp_path / "ep", specs)
    pairs = sample_pairs(episodes, ["P1", "P2", "P3"], [4, 8], seed=7)
    reserve = sample_reserve(episodes, ["P1", "P2", "P3"], [4, 8], seed=7, n_reserve=6)
    longer = sample_pairs(episodes, ["P1", "P2", "P3"], [14], seed=7)
    tail = longer[longer["pair_index"] >= 8].drop(columns="first_checkpoint").reset_index(drop=True)
    assert reserve.drop(columns="first_checkpoint").equals(tail)
    assert (reserve["first_checkpoint"] == -1).all() and len(reserve) == 3 * 6
    # The planned comparisons are untouched by drawing a reserve.
    assert pairs.equals(sample_pairs(episodes, ["P1", "P2", "P3"], [4, 8], seed=7))
    assert sample_reserve(episodes, ["P1", "P2", "P3"], [4, 8], seed=7, n_reserve=0).empty


@pytest.mark.parametrize("group", ["default", "vllm", "transformers"])
def test_judge_shipped_configs_build(group):
    """Every judge the configs ship builds (no model is loaded or contacted)."""
    from pathlib import Path

    from r2s_eval.config import compose_config

    conf = Path(__file__).resolve().parents[2] / "conf"
    judges = compose_config(conf, experiment="smoke", overrides=[f"judges={group}"])["judges"]
    assert judges
    for name, jc in judges.items():
        judge = make_judge(jc)
        assert judge.name
        if group == "vllm":
            assert judge.backend == "openai" and judge.stage_cfg["swap_share"] == 1.0


def test_judge_paper_experiment_lists_the_eight_vlms():
    from pathlib import Path

    from r2s_eval.config import compose_config

    conf = Path(__file__).resolve().parents[2] / "conf"
    judges = compose_config(conf, experiment="paper")["judges"]
    models = sorted(j["model"] for j in judges.values())
    assert len(models) == 8 and sum("Qwen3-VL" in m for m in models) == 3
    assert sum("gemma-3" in m for m in models) == 3 and sum("LLaVA-OneVision-1.5" in m for m in models) == 2
    assert sorted(compose_config(conf, experiment="smoke")["judges"]) == ["kinematic"]

"""Prompt templates, strict reply parsing, frame sampling and the replacement reserve."""

from __future__ import annotations

import numpy as np
import pytest

from r2s_eval.compare.sampling import sample_pairs, sample_reserve
from r2s_eval.judge import CRITERIA, CriterionNote, Description, make_judge
from r2s_eval.judge import prompting
from r2s_eval.judge.clip_frames import frame_indices, sample_clip
from r2s_eval.judge.prompting import (
    PROMPT_SETS,
    TEMPLATES,
    description_text,
    fields,
    parse_description,
    parse_letter,
    render,
    template,
    templates_sha,
)
from r2s_eval.rollout.mp4 import write_video


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


@pytest.mark.parametrize("prompt_set", PROMPT_SETS)
def test_judge_templates_take_only_the_instruction_and_the_recordings(prompt_set):
    assert set(TEMPLATES) == {"system", "describe", "compare", "compare_videos", "reask"}
    expected = {"system": set(), "reask": set(), "describe": {"instruction", "video"},
                "compare": {"instruction", "description_a", "description_b"},
                "compare_videos": {"instruction", "video_a", "video_b"}}
    assert {t: fields(t, prompt_set) for t in TEMPLATES} == expected
    with pytest.raises(ValueError, match="takes fields"):
        render("compare", prompt_set=prompt_set, instruction="x", description_a="a", description_b="b", policy="act")
    with pytest.raises(ValueError, match="takes fields"):
        render("describe", prompt_set=prompt_set, instruction="x", video="", duration_s=3.0)
    for label in ("successful", "partially successful", "failed"):
        assert label in render("describe", prompt_set=prompt_set, instruction="x", video="")
    # No template speaks of time, length or counts of frames.
    for t in TEMPLATES:
        text = template(t, prompt_set).lower()
        for word in ("second", "duration", "fps", "frame rate", "how long", "length", "{n_"):
            assert word not in text, (t, word)
    # What the compare prompt shows of a description: the sections, not who wrote it.
    d = Description(criteria={"task_progress": CriterionNote("done", label="successful")}, summary="ok",
                    judge="secret-judge-name")
    text = description_text(d)
    assert "Task success: successful. done" in text and "secret-judge-name" not in text
    assert "Motion smoothness: (not described)" in text


def test_judge_balanced_prompts_rank_no_criterion_first():
    aspects = ("motion smoothness", "action continuity", "task success", "force/effort control")
    for name in ("compare", "compare_videos"):
        balanced, success_first = template(name, "balanced").lower(), template(name, "success_first").lower()
        assert all(a in balanced for a in aspects) and "equal weight" in balanced
        assert "first" not in balanced and "when both are equally successful" not in balanced
        assert "judge task success first" in success_first
    # The describe prompt is shared and keeps the explicit outcome label as one of four aspects.
    assert template("describe", "balanced") == template("describe", "success_first")
    assert "equal weight" in template("describe").lower()
    with pytest.raises(ValueError, match="unknown prompt_set 'strict'"):
        template("compare", "strict")


def test_judge_frames_always_the_same_count_spread_over_the_clip(tmp_path):
    frames = [np.full((32, 48, 3), 4 * i, np.uint8) for i in range(60)]  # 3 s at 20 fps
    write_video(tmp_path / "v.mp4", frames, fps=20)
    clip = sample_clip(tmp_path / "v.mp4", n_frames=8)
    assert clip.frames.shape == (8, 32, 48, 3) and not hasattr(clip, "duration_s") and not hasattr(clip, "times_s")
    # First and last frame included, evenly spaced in between (frame i has brightness 4 i).
    assert np.abs(clip.frames.mean(axis=(1, 2, 3)) - 4 * frame_indices(60, 8)).max() < 2
    assert frame_indices(60, 8).tolist() == [0, 8, 17, 25, 34, 42, 51, 59]
    # A clip shorter than the count repeats frames: 8 frames still.
    write_video(tmp_path / "short.mp4", frames[:3], fps=20)
    assert sample_clip(tmp_path / "short.mp4", n_frames=8).frames.shape[0] == 8
    assert frame_indices(3, 8).tolist() == [0, 0, 1, 1, 1, 1, 2, 2]
    assert {len(frame_indices(n, 32)) for n in (1, 5, 31, 32, 33, 600)} == {32}
    small = sample_clip(tmp_path / "v.mp4", n_frames=8, max_side_px=24)
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
    assert a.cfg["prompt_set"] == "balanced"
    with pytest.raises(ValueError, match=r"\['fps'\] no longer exist.*exactly max_frames"):
        make_judge({**base, "fps": 10.0})
    with pytest.raises(ValueError, match="unknown prompt_set"):
        make_judge({**base, "prompt_set": "strict"})
    assert make_judge({"backend": "kinematic", "swap_share": 0.5}).stage_cfg["swap_share"] == 0.5
    with pytest.raises(ValueError, match="mode must be one of"):
        make_judge({**base, "mode": "three_step"})


def test_judge_prompt_set_and_prompt_texts_are_part_of_the_cache_identity(monkeypatch):
    base = {"backend": "openai", "model": "m"}
    balanced, first = make_judge(base), make_judge({**base, "prompt_set": "success_first"})
    assert balanced.identity()["prompts"] == templates_sha("balanced") != templates_sha("success_first")
    assert balanced.identity() != first.identity()
    assert balanced.identity()["answer_config"] != first.identity()["answer_config"]
    # Editing any prompt file, shared or not, changes the identity (and so every cache key).
    read = prompting._read
    for edited in ("describe.txt", "system.txt", "reask.txt", "compare.balanced.txt", "compare_videos.balanced.txt"):
        monkeypatch.setattr(prompting, "_read", lambda f, e=edited: read(f) + (" (edited)" if f == e else ""))
        assert make_judge(base).identity() != balanced.identity(), edited
    # ...but a file of the other set does not touch this one.
    other = "compare.success_first.txt"
    monkeypatch.setattr(prompting, "_read", lambda f: read(f) + (" (edited)" if f == other else ""))
    assert make_judge(base).identity() == balanced.identity()
    assert make_judge({**base, "prompt_set": "success_first"}).identity() != first.identity()


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


def test_judge_stage_options_default_from_conf():
    """A judge entry that leaves out its stage options gets conf/judge_options.yaml's values."""
    from pathlib import Path

    import yaml

    from r2s_eval.judge import STAGE_OPTIONS, stage_defaults

    conf = yaml.safe_load((Path(__file__).resolve().parents[2] / "conf" / "judge_options.yaml").read_text())
    assert stage_defaults() == conf and sorted(conf) == sorted(STAGE_OPTIONS)
    assert make_judge({"backend": "kinematic"}).stage_cfg == conf
    own = make_judge({"backend": "kinematic", "reserve": 7}).stage_cfg
    assert own["reserve"] == 7 and own["mode"] == conf["mode"]


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
    assert sorted(compose_config(conf, experiment="smoke")["judges"]) == ["kinematic", "video"]

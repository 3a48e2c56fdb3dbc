"""Nothing a VLM judge receives besides the pixels can tell a success from a failure.

Rollouts stop soon after success, so in these synthetic rollouts (as in real ones) successes are
short and failures long: the episode length alone would separate them perfectly. Every request a
VLM judge sends (describe, compare, compare videos, re-ask; two-step and one-step; backend-neutral
messages, the openai wire format with frames and with a video part, and the transformers
conversation) is captured, and across episodes:

* its text parts are identical once the task instruction (and, when comparing descriptions, the
  two descriptions, which the judge wrote from the pixels alone) are masked;
* it carries the same number of frames per clip, at the same size (and for a video part, the same
  container frame count, rate and duration).

So (prompt text, frame count) is constant given the task, and no predictor of success built on
them beats the base rate of the task.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from r2s_eval.compare.sampling import sample_pairs
from r2s_eval.judge import Description, describe_rollouts, judge_pairs, make_judge
from r2s_eval.judge.clip_frames import VIDEO_PART_FPS, Clip
from r2s_eval.judge.prompting import PROMPT_SETS, description_text
from r2s_eval.judge.transformers_backend import TransformersJudge
from r2s_eval.judge.vlm import COMMON_DEFAULTS, Reply, VLMJudge
from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.utils.io import file_sha256


from tests.helpers.chat_server import ChatServer
from tests.helpers.videos import INSTRUCTIONS, make_rollouts

N_FRAMES = 16
POLICIES = ["Fails", "Succeeds"]


@pytest.fixture(scope="module")
def rollouts(tmp_path_factory):
    """Two tasks x two policies x three inits: bright short successes, dark long failures, with
    lengths below, at and above the frame count."""
    levels, lengths = {}, {}
    for t, task in enumerate(INSTRUCTIONS):
        for init in range(3):
            levels[("Succeeds", task, init)] = 0.75 + 0.01 * init
            lengths[("Succeeds", task, init)] = (5, 11, 16)[init] + t
            levels[("Fails", task, init)] = 0.15 + 0.01 * init
            lengths[("Fails", task, init)] = (30, 45, 60)[init] + t
    dirs = make_rollouts(tmp_path_factory.mktemp("rollouts"), levels, lengths)
    episodes = load_episodes(dirs)
    # The test has teeth: length alone predicts the outcome perfectly.
    assert best_accuracy(list(zip(episodes["task"], episodes["length"])), episodes["success"]) == 1.0
    assert chance(episodes) == 0.5
    return episodes


def best_accuracy(features: list[Any], outcomes: Any) -> float:
    """Accuracy of the best possible predictor of `outcomes` that sees only `features`: the
    majority outcome within each distinct feature value."""
    groups: dict[Any, Counter] = defaultdict(Counter)
    for f, y in zip(features, outcomes):
        groups[f][bool(y)] += 1
    return sum(max(c.values()) for c in groups.values()) / len(features)


def chance(episodes) -> float:
    """The base rate: the best prediction from the task alone (which the instruction states)."""
    return best_accuracy(list(episodes["task"]), episodes["success"])


def masker(episodes, desc=None):
    """Replace the per-episode text that legitimately varies (instruction; descriptions, which the
    judge itself wrote from pixels) with placeholders."""
    known = [(i, "<instruction>") for i in set(episodes["instruction"])]
    if desc is not None:
        known += [(description_text(Description.from_json(d)), "<description>") for d in desc["description"]]
    known.sort(key=lambda kv: -len(kv[0]))  # longest first: a description contains no instruction

    def mask(text: str) -> str:
        for s, placeholder in known:
            text = text.replace(s, placeholder)
        return text

    return mask


def describe_reply(frames: np.ndarray) -> str:
    """A reply that, like a model's, depends on the pixels only."""
    b = float(frames.mean()) / 255.0
    label = "successful" if b >= 0.6 else "failed"
    return (f"Motion smoothness: steady, brightness {b:.3f}.\nAction continuity: no pauses.\n"
            f"Task success: {label}. That is what the frames show.\nForce/effort control: gentle.\n"
            "Summary: plain.")


class CaptureJudge(VLMJudge):
    """A VLM judge whose 'model' records every backend-neutral request it is sent, with the
    content-hash names of the recordings behind it (to map requests back to episodes).
    A comparison's first answer is never a letter, so every comparison is also re-asked."""

    backend = "capture"
    DEFAULTS = {**COMMON_DEFAULTS, "backend": "capture"}

    def __init__(self, cfg):
        super().__init__({"backend": "capture", "model": "capture-model", "max_frames": N_FRAMES, **cfg})
        self.sent: list[tuple[str, tuple[str, ...], list[dict]]] = []
        self._asking: tuple[str, tuple[str, ...]] = ("", ())

    def describe(self, rollout):
        self._asking = ("describe", (rollout.video_path.stem,))
        return super().describe(rollout)

    def compare(self, a, b, instruction):
        self._asking = ("compare", ())
        return super().compare(a, b, instruction)

    def compare_videos(self, a, b, instruction):
        self._asking = ("compare_videos", (a.video_path.stem, b.video_path.stem))
        return super().compare_videos(a, b, instruction)

    def _generate(self, messages):
        kind, videos = self._asking
        self.sent.append((kind, videos, messages))
        if kind == "describe":
            (clip,) = [p for p in messages[-1]["content"] if isinstance(p, Clip)]
            return Reply(describe_reply(clip.frames))
        reasked = any(m["role"] == "assistant" for m in messages)
        return Reply("A" if reasked else "Both look fine to me.")


def run_stages(judge, episodes, cache, mode: str):
    pairs = sample_pairs(episodes, POLICIES, [6], seed=3)
    if mode == "two_step":
        desc = describe_rollouts(episodes, ".", judge, cache)
        judge_pairs(pairs, desc, judge, cache)
        return desc
    judge_pairs(pairs, None, judge, cache, episodes_df=episodes, episodes_dir=".")
    return None


def assert_no_cues(signatures: dict[str, list[tuple]], expect_kinds: set[str]) -> None:
    """Per request kind, one signature (masked texts, frame counts and sizes) for all requests."""
    assert set(signatures) == expect_kinds
    for kind, sigs in signatures.items():
        assert len(sigs) > 1 and len(set(sigs)) == 1, (kind, Counter(sigs).most_common(3))


@pytest.mark.parametrize("prompt_set", PROMPT_SETS)
@pytest.mark.parametrize("mode", ["two_step", "one_step"])
def test_vlm_requests_are_identical_across_episodes_but_for_instruction_and_pixels(rollouts, tmp_path, mode,
                                                                                  prompt_set):
    episodes = rollouts
    judge = CaptureJudge({"mode": mode, "prompt_set": prompt_set})
    desc = run_stages(judge, episodes, tmp_path / "cache", mode)
    mask = masker(episodes, desc)

    signatures: dict[str, list[tuple]] = defaultdict(list)
    per_episode: dict[str, set] = defaultdict(set)  # video sha -> (masked text, frames) it was shown with
    for kind, videos, messages in judge.sent:
        reask = any(m["role"] == "assistant" for m in messages)
        parts = tuple(
            (m["role"], tuple(("clip", p.frames.shape) if isinstance(p, Clip) else mask(p) for p in m["content"]))
            for m in messages
        )
        signatures[kind + (" re-ask" if reask else "")].append(parts)
        clips = [p for m in messages for p in m["content"] if isinstance(p, Clip)]
        assert len(clips) == len(videos)
        for sha, clip in zip(videos, clips):
            assert clip.frames.shape == (N_FRAMES, 32, 32, 3)
            text = tuple(p for _, ps in parts for p in ps if isinstance(p, str))
            per_episode[sha].add((text, clip.frames.shape[0]))

    kinds = {"describe", "compare", "compare re-ask"} if mode == "two_step" else {"compare_videos",
                                                                                   "compare_videos re-ask"}
    assert_no_cues(signatures, kinds)
    # The instruction is the only text that differs, and it is the task's.
    seen = {i for _, _, msgs in judge.sent for m in msgs for p in m["content"] if isinstance(p, str)
            for i in INSTRUCTIONS.values() if i in p}
    assert seen == set(INSTRUCTIONS.values())

    # (prompt text, frame count) as seen per episode predicts success no better than chance.
    sha_of = {file_sha256(Path(v)): e for e, v in zip(episodes["episode_id"], episodes["video_path"])}
    shown = episodes[episodes["episode_id"].isin({sha_of[s] for s in per_episode})]
    assert shown.groupby("task")["success"].nunique().eq(2).all() and shown["task"].nunique() == 2
    feature_of = {sha_of[s]: frozenset(v) for s, v in per_episode.items()}
    features = [(t, feature_of[e]) for t, e in zip(shown["task"], shown["episode_id"])]
    by_task = defaultdict(set)
    for t, f in features:
        by_task[t].add(f)
    assert all(len(f) == 1 for f in by_task.values())  # constant given the task: no information
    assert best_accuracy(features, shown["success"]) == best_accuracy(list(shown["task"]), shown["success"])
    assert best_accuracy(list(zip(shown["task"], shown["length"])), shown["success"]) == 1.0


@pytest.mark.parametrize("video_input", ["frames", "video"])
@pytest.mark.parametrize("mode", ["two_step", "one_step"])
def test_openai_wire_requests_carry_no_length(rollouts, tmp_path, mode, video_input):
    episodes = rollouts
    with ChatServer() as server:
        judge = make_judge({"backend": "openai", "base_url": server.url, "model": "test-vlm",
                            "max_frames": N_FRAMES, "video_input": video_input, "mode": mode})
        desc = run_stages(judge, episodes, tmp_path / "cache", mode)
    mask = masker(episodes, desc)
    assert all(e["status"] == 200 for e in server.log)
    signatures: dict[str, list[tuple]] = defaultdict(list)
    for e in server.log:
        texts = tuple((role, mask(t)) for role, t in e["texts"])
        clips = 1 if e["kind"] == "describe" else 2 if e["kind"] == "compare_videos" else 0
        if video_input == "frames":
            assert e["n_images"] == clips * N_FRAMES and not e["videos"]
        else:
            assert e["n_images"] == 0 and len(e["videos"]) == clips
            for v in e["videos"]:
                assert v["frames"] == N_FRAMES and v["fps"] == VIDEO_PART_FPS
        videos = tuple(tuple(sorted(v.items())) for v in e["videos"])
        signatures[e["kind"]].append((texts, e["n_images"], videos))
    assert_no_cues(signatures, {"describe", "compare"} if mode == "two_step" else {"compare_videos"})
    # The pixels still speak: the judge told successes from failures by brightness alone.
    if desc is not None:
        success = dict(zip(episodes["episode_id"], episodes["success"]))
        assert all((lab == "successful") == success[e] for e, lab in zip(desc["episode_id"], desc["progress_label"]))


class ConversationJudge(TransformersJudge):
    """The transformers backend up to the chat template: records the conversation, loads no model."""

    def __init__(self, cfg):
        super().__init__({"backend": "transformers", "model": "no-model", "max_frames": N_FRAMES, **cfg})
        self.conversations: list[list[dict]] = []

    def _generate(self, messages):
        conv = self._conversation(messages)
        self.conversations.append(conv)
        images = [c["image"] for m in conv for c in m["content"] if c["type"] == "image"]
        if any("Describe what the robot does" in c.get("text", "") for m in conv for c in m["content"]):
            return Reply(describe_reply(np.stack([np.asarray(im) for im in images])))
        return Reply("B")


@pytest.mark.parametrize("mode", ["two_step", "one_step"])
def test_transformers_conversations_carry_no_length(rollouts, tmp_path, mode):
    episodes = rollouts
    judge = ConversationJudge({"mode": mode})
    desc = run_stages(judge, episodes, tmp_path / "cache", mode)
    mask = masker(episodes, desc)
    signatures: dict[str, list[tuple]] = defaultdict(list)
    for conv in judge.conversations:
        parts = tuple((m["role"], tuple(("image", c["image"].size) if c["type"] == "image" else mask(c["text"])
                                        for c in m["content"])) for m in conv)
        n_images = sum(1 for _, ps in parts for p in ps if isinstance(p, tuple))
        kind = "describe" if n_images == N_FRAMES else "compare_videos" if n_images == 2 * N_FRAMES else "compare"
        assert n_images in (0, N_FRAMES, 2 * N_FRAMES)
        signatures[kind].append(parts)
    assert_no_cues(signatures, {"describe", "compare"} if mode == "two_step" else {"compare_videos"})


def test_prompt_sets_never_share_cached_answers(rollouts, tmp_path):
    episodes = rollouts.head(4)
    cache = tmp_path / "cache"
    first = CaptureJudge({"prompt_set": "balanced"})
    describe_rollouts(episodes, ".", first, cache)
    assert len(first.sent) == 4
    again = CaptureJudge({"prompt_set": "balanced"})
    assert describe_rollouts(episodes, ".", again, cache).attrs["stats"]["calls"] == 0 and not again.sent
    other = CaptureJudge({"prompt_set": "success_first"})
    st = describe_rollouts(episodes, ".", other, cache).attrs["stats"]
    # The describe prompt is shared, yet the other set's answers are asked anew, at both levels.
    assert st["calls"] == st["requests"] == 4 and st["cache_hits"] == 0 and len(other.sent) == 4

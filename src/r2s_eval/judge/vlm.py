"""The two-step VLM judge, independent of where the model runs.

``VLMJudge`` holds the method; a backend only implements ``_generate(messages) -> Reply``:

* describe: sample the video's frames (``frames.py``), ask the ``describe`` prompt, cut the reply
  into the four criteria and the summary (``prompting.parse_description``; absent sections are
  flagged in ``Description.missing``);
* compare: show the two descriptions (``compare`` prompt) and parse one letter strictly; an invalid
  reply is asked once more (``reask`` prompt), then ``InvalidAnswer`` is raised;
* compare_videos (one-step mode): show both videos directly (``compare_videos`` prompt).

A backend raises ``MalformedReply`` when the server kept answering with something that is not a
chat reply (after its retries): a comparison then counts as an invalid answer (``InvalidAnswer``,
its replies say why), a description as one whose sections are all missing (``raw_text`` says
why), so one bad reply never stops a stage. A backend that bounds the time of one judge call
(``call_deadline_s``) reads what is left of it with ``_time_left()``.

What a model receives besides the pixels is the same for every episode of a task: the prompt text
of the chosen ``prompt_set`` with the task instruction filled in (no duration, frame count, frame
rate, file name or id), and exactly ``max_frames`` frames per clip whatever its length. Episodes
stop soon after success, so any of those would tell a success from a failure without looking.

Messages are backend-neutral: ``[{"role": ..., "content": [str | Clip, ...]}]``. Every request is
kept in a content-addressed request cache when the stage driver attaches one, so a run killed
between an invalid answer and its re-ask repeats neither.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import logging
import threading
import time
from abc import abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from r2s_eval.errors import ConfigError, DataError
from r2s_eval.judge.base import Description, InvalidAnswer, Judge, RolloutInput, Verdict
from r2s_eval.judge.cache import AnswerCache, cache_key
from r2s_eval.judge.clip_frames import Clip, sample_clip
from r2s_eval.judge.prompting import (
    DEFAULT_PROMPT_SET,
    check_prompt_set,
    description_text,
    parse_description,
    parse_letter,
    render,
    split_on,
    strip_thinking,
    templates_sha,
)
from r2s_eval.judge.usage import record_usage
from r2s_eval.utils.io import config_hash

log = logging.getLogger(__name__)

# Placeholders the rendered prompt is split on; the clip goes where they stood.
_VIDEO, _VIDEO_A, _VIDEO_B = "\x00video\x00", "\x00video_a\x00", "\x00video_b\x00"

COMMON_DEFAULTS: dict[str, Any] = {
    "backend": None,
    "name": None,
    "model": None,  # required: the served model name, or a checkpoint path / hub id
    # Frames shown per video: always exactly this many, spread evenly from the first frame to the
    # last (a short clip repeats frames), so the count never reveals the episode's length.
    "max_frames": 32,
    "prompt_set": DEFAULT_PROMPT_SET,  # "balanced" (the four criteria weighed equally) or "success_first"
    "max_side_px": None,  # shrink frames so the longer side is at most this
    "max_new_tokens": 1024,
    "system_role": True,  # False: the system text opens the user turn (models without a system role)
}


@dataclass(frozen=True)
class Reply:
    text: str
    tokens_in: int = 0
    tokens_out: int = 0


class MalformedReply(Exception):
    """The server answered, but never with a chat reply (not JSON, no choices, empty content)."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason  # short and fixed, e.g. "no 'choices'": it is stored with the answer


def merge_config(kind: str, defaults: Mapping[str, Any], cfg: Mapping[str, Any]) -> dict[str, Any]:
    unknown = set(cfg) - set(defaults)
    if unknown:
        raise ConfigError(f"{kind} judge: unknown config keys {sorted(unknown)}; known: {sorted(defaults)}")
    out = copy.deepcopy(dict(defaults))
    out.update(copy.deepcopy(dict(cfg)))
    return out


class VLMJudge(Judge):
    """Base of the VLM backends (see the module docstring)."""

    prompt_version = "vlm-v2"  # v2: fixed frame count, no durations in prompts, prompt sets
    inputs = ("video",)
    DEFAULTS: ClassVar[dict[str, Any]] = COMMON_DEFAULTS
    # Keys that say how to reach or run the model, not what it answers: outside the cache keys.
    TRANSPORT_KEYS: ClassVar[frozenset[str]] = frozenset({"name"})

    def __init__(self, cfg: Mapping[str, Any] | None = None):
        super().__init__(cfg)
        removed = sorted({"fps", "over_budget"} & set(self.cfg))
        if removed:
            raise ConfigError(
                f"{self.backend} judge: {removed} no longer exist; every video is shown as exactly max_frames "
                "frames spread over the whole clip, so the number of frames cannot reveal its length"
            )
        self.cfg = merge_config(self.backend, self.DEFAULTS, self.cfg)
        if self.cfg["backend"] != self.backend:
            raise ValueError(f"{self.backend} judge built with backend {self.cfg['backend']!r}")
        if not self.cfg["model"]:
            raise ConfigError(f"{self.backend} judge needs a 'model'")
        try:
            check_prompt_set(self.cfg["prompt_set"])
        except ValueError as e:
            raise ConfigError(f"{self.backend} judge: {e}") from None
        if int(self.cfg["max_frames"]) < 1 or int(self.cfg["max_new_tokens"]) < 1:
            raise ConfigError(f"{self.backend} judge: max_frames and max_new_tokens must be positive")
        self.prompt_set = str(self.cfg["prompt_set"])
        self._requests: AnswerCache | None = None
        self._local = threading.local()  # the deadline of the judge call running in this thread
        # Every key that changes an answer is in the cache identity: the answer config (prompt_set
        # included) and the hash of the set's prompt texts, so another set or an edited prompt
        # file gets new keys at both cache levels (per stage answer and per request).
        self._identity = {
            "backend": self.backend,
            "answer_config": config_hash({k: v for k, v in self.cfg.items() if k not in self.TRANSPORT_KEYS}),
            "prompts": templates_sha(self.prompt_set),
            "prompt_version": self.prompt_version,
        }

    @property
    def name(self) -> str:
        return str(self.cfg.get("name") or self.cfg["model"])

    def identity(self) -> dict[str, str]:
        """Model, generation and frame settings, the prompt set and its template texts; not the
        judge's name or server address, so every judge entry and rerun using the same model shares
        the answers."""
        return dict(self._identity)

    def attach_cache(self, cache_dir: str | Path) -> None:
        self._requests = AnswerCache(cache_dir, "requests")

    # ------------------------------------------------------------------ deadline
    @contextlib.contextmanager
    def _call_scope(self) -> Iterator[None]:
        """One judge call (a description, or a comparison with its re-ask): its deadline starts."""
        limit = self.cfg.get("call_deadline_s")  # only backends that can bound a request have it
        self._local.deadline = time.monotonic() + float(limit) if limit else None
        try:
            yield
        finally:
            self._local.deadline = None

    def _time_left(self) -> float | None:
        """Seconds left of the current judge call's ``call_deadline_s``; None: no deadline."""
        deadline = getattr(self._local, "deadline", None)
        return None if deadline is None else deadline - time.monotonic()

    # ------------------------------------------------------------------ backend
    @abstractmethod
    def _generate(self, messages: list[dict[str, Any]]) -> Reply:
        """Greedy reply to backend-neutral messages (see the module docstring)."""

    # ------------------------------------------------------------------ requests
    def _chat(self, messages: list[dict[str, Any]]) -> Reply:
        digest = [
            {"role": m["role"], "content": [{"clip": p.sha256} if isinstance(p, Clip) else p for p in m["content"]]}
            for m in messages
        ]
        key = cache_key({"judge": self._identity, "messages": digest}) if self._requests is not None else None
        if key is not None:
            hit = self._requests.get(key)
            if hit is not None:
                record_usage(request_cache_hits=1)
                return Reply(str(hit["text"]))
        reply = self._generate(messages)
        record_usage(requests=1, tokens_in=reply.tokens_in, tokens_out=reply.tokens_out)
        if key is not None:
            self._requests.put(
                key,
                {"text": reply.text, "tokens_in": reply.tokens_in, "tokens_out": reply.tokens_out},
                {"judge": self._identity, "messages_sha": hashlib.sha256(repr(digest).encode()).hexdigest()},
            )
        return reply

    def _messages(self, content: list[Any]) -> list[dict[str, Any]]:
        system = render("system", prompt_set=self.prompt_set)
        if self.cfg["system_role"]:
            return [{"role": "system", "content": [system]}, {"role": "user", "content": content}]
        return [{"role": "user", "content": [system + "\n\n", *content]}]

    def _clip(self, path: Path | None) -> Clip:
        if path is None:
            raise DataError(f"the {self.backend} judge watches videos; the rollout input has no video_path")
        return sample_clip(path, int(self.cfg["max_frames"]), self.cfg["max_side_px"])

    def _ask_letter(self, content: list[Any]) -> Verdict:
        messages = self._messages(content)
        try:
            first = self._chat(messages)
        except MalformedReply as e:
            log.warning("%s", e)
            raise InvalidAnswer(str(e), [f"malformed reply: {e.reason}"]) from None
        letter = parse_letter(first.text)
        if letter is not None:
            return Verdict(letter, strip_thinking(first.text))
        record_usage(reasks=1)
        again = messages + [
            {"role": "assistant", "content": [first.text]},
            {"role": "user", "content": [render("reask", prompt_set=self.prompt_set)]},
        ]
        try:
            second = self._chat(again)
        except MalformedReply as e:
            log.warning("%s", e)
            raise InvalidAnswer(str(e), [first.text, f"malformed reply: {e.reason}"]) from None
        letter = parse_letter(second.text)
        if letter is not None:
            return Verdict(letter, strip_thinking(second.text))
        raise InvalidAnswer("no valid letter (A or B) after asking once more", [first.text, second.text])

    # ------------------------------------------------------------------ the method
    def describe(self, rollout: RolloutInput) -> Description:
        with self._call_scope():
            clip = self._clip(rollout.video_path)
            text = render("describe", prompt_set=self.prompt_set, instruction=rollout.instruction, video=_VIDEO)
            content = [clip if p == _VIDEO else p for p in split_on(text, _VIDEO)]
            try:
                reply = self._chat(self._messages(content))
            except MalformedReply as e:
                # No reply to parse: every section is missing, and raw_text (never shown in a
                # compare prompt) says why.
                log.warning("%s", e)
                return Description(criteria={}, summary="", judge=str(self.cfg["model"]),
                                   raw_text=f"malformed reply: {e.reason}")
            return parse_description(reply.text, judge=str(self.cfg["model"]))

    def compare(self, a: Description, b: Description, instruction: str) -> Verdict:
        with self._call_scope():
            text = render(
                "compare", prompt_set=self.prompt_set, instruction=instruction,
                description_a=description_text(a), description_b=description_text(b),
            )
            return self._ask_letter([text])

    def compare_videos(self, a: RolloutInput, b: RolloutInput, instruction: str) -> Verdict:
        with self._call_scope():
            ca, cb = self._clip(a.video_path), self._clip(b.video_path)
            text = render("compare_videos", prompt_set=self.prompt_set, instruction=instruction,
                          video_a=_VIDEO_A, video_b=_VIDEO_B)
            clips = {_VIDEO_A: ca, _VIDEO_B: cb}
            return self._ask_letter([clips.get(p, p) for p in split_on(text, _VIDEO_A, _VIDEO_B)])

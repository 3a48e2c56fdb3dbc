"""Backend "openai": any OpenAI-compatible chat-completions server (vLLM, SGLang, a hosted API).

Video goes in as JPEG frames (``video_input: frames``) or as one H.264 video part
(``video_input: video``, which vLLM accepts for Qwen-VL models). Requests are greedy
(temperature 0) with ``max_new_tokens`` as the token limit. The API key is read from the
environment variable named by ``api_key_env`` and is never logged or stored.

Faults, and the keys that bound them (none of them changes an answer, so none is in the cache
keys):

* connection errors, timeouts, 408, 429 and 5xx are retried, at most ``max_retries`` (6) times,
  after an exponential backoff: ``backoff_s`` (1 s), doubling per retry, at most ``backoff_max_s``
  (60 s); other HTTP errors fail at once;
* a 200 reply that is no chat answer (a body that is not JSON, no ``choices`` or an empty list,
  empty message content) is retried the same way and counted as ``malformed``; when the last
  retry is malformed too, a comparison counts as an invalid answer (excluded and replaced) and a
  description as one with every section missing: the stage goes on;
* ``Retry-After`` (seconds or an HTTP date) is honoured: the client never comes back before the
  server asked, even past ``backoff_max_s``, up to ``retry_after_max_s`` (300 s). A server that
  asks for longer fails that request at once, saying what it asked; raise the key to wait;
* ``call_deadline_s`` (900 s) bounds one judge call (one description, or one comparison with its
  re-ask), retries, waits and requests included: each request may take at most ``timeout_s``
  (120 s) or what is left of the deadline, whichever is less, and a wait that would pass the
  deadline ends the retries. With the defaults one call therefore fails within 900 s at the
  latest, instead of up to 7 x 600 s of requests plus the waits. (The request timeout bounds
  connecting and each read and write, as httpx does: a server that keeps trickling bytes slower
  than that is not cut off.)

A request that fails past all of this raises ``JudgeError``; the stage names the episode or pair.
"""

from __future__ import annotations

import datetime as dt
import email.utils
import json
import logging
import os
import threading
import time
from typing import Any

from r2s_eval.errors import ConfigError, JudgeError
from r2s_eval.judge.base import register_judge
from r2s_eval.judge.clip_frames import Clip, jpeg_data_urls, mp4_data_url
from r2s_eval.judge.usage import record_usage
from r2s_eval.judge.vlm import COMMON_DEFAULTS, MalformedReply, Reply, VLMJudge

log = logging.getLogger(__name__)

VIDEO_INPUTS = ("frames", "video")


def _retry_after_s(err: Exception) -> float | None:
    """The wait a ``Retry-After`` header asks for, in seconds (delta-seconds or HTTP-date form)."""
    response = getattr(err, "response", None)
    value = response.headers.get("retry-after") if response is not None else None
    if value is None:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    if when.tzinfo is None:  # HTTP dates are GMT
        when = when.replace(tzinfo=dt.timezone.utc)
    return max(0.0, (when - dt.datetime.now(dt.timezone.utc)).total_seconds())


class _Malformed(Exception):
    """One 200 reply that is not a chat answer; the message is a short fixed reason."""


def _count(usage: Any, name: str) -> int:
    value = getattr(usage, name, 0)
    return value if isinstance(value, int) else 0


def _reply(resp: Any) -> Reply:
    """The reply's text and token counts, or ``_Malformed`` saying what is wrong with it."""
    # The client builds its response object without validating it (and hands back the bare body
    # when that is not a JSON object), so every level is checked here.
    choices = getattr(resp, "choices", None)
    if not isinstance(choices, list):
        raise _Malformed("no 'choices'")
    if not choices:
        raise _Malformed("empty 'choices'")
    content = getattr(getattr(choices[0], "message", None), "content", None)
    if not isinstance(content, str) or not content.strip():
        raise _Malformed("empty message content")
    usage = getattr(resp, "usage", None)
    return Reply(text=content, tokens_in=_count(usage, "prompt_tokens"), tokens_out=_count(usage, "completion_tokens"))


@register_judge("openai")
class OpenAIJudge(VLMJudge):
    DEFAULTS = {
        **COMMON_DEFAULTS,
        "backend": "openai",
        "base_url": "http://127.0.0.1:8000/v1",
        "api_key_env": None,  # name of the environment variable holding the key; None: no key
        "video_input": "frames",  # "frames" (image parts) or "video" (one video part)
        "jpeg_quality": 90,
        "extra_body": {},  # server-specific request fields, e.g. vLLM's mm_processor_kwargs
        "timeout_s": 120.0,  # one request, at most; never more than what is left of call_deadline_s
        "max_retries": 6,
        "backoff_s": 1.0,  # first wait; doubles per retry
        "backoff_max_s": 60.0,  # longest backoff of our own; a server's Retry-After may ask for more
        "retry_after_max_s": 300.0,  # longest Retry-After honoured; a longer one fails the request
        "call_deadline_s": 900.0,  # one description or comparison, retries and waits included
    }
    TRANSPORT_KEYS = frozenset({
        "name", "base_url", "api_key_env", "timeout_s", "max_retries", "backoff_s", "backoff_max_s",
        "retry_after_max_s", "call_deadline_s",
    })

    def __init__(self, cfg=None):
        super().__init__(cfg)
        if self.cfg["video_input"] not in VIDEO_INPUTS:
            raise ConfigError(f"openai judge: video_input must be one of {VIDEO_INPUTS}, got {self.cfg['video_input']!r}")
        for key in ("timeout_s", "call_deadline_s"):
            if not _number(self.cfg[key]) or self.cfg[key] <= 0:
                raise ConfigError(f"openai judge: {key} must be a number of seconds > 0, got {self.cfg[key]!r}")
        for key in ("backoff_s", "backoff_max_s", "retry_after_max_s"):
            if not _number(self.cfg[key]) or self.cfg[key] < 0:
                raise ConfigError(f"openai judge: {key} must be a number of seconds >= 0, got {self.cfg[key]!r}")
        if not isinstance(self.cfg["max_retries"], int) or self.cfg["max_retries"] < 0:
            raise ConfigError(f"openai judge: max_retries must be an integer >= 0, got {self.cfg['max_retries']!r}")
        self._client = None
        self._lock = threading.Lock()

    def _api_key(self) -> str:
        var = self.cfg["api_key_env"]
        if not var:
            return "EMPTY"  # servers started without a key accept any
        key = os.environ.get(str(var))
        if not key:
            raise ConfigError(f"judge {self.name!r}: environment variable {var} (api_key_env) is not set")
        return key

    def client(self):
        with self._lock:
            if self._client is None:
                import openai

                # Retries are ours (counted and logged), so the client's own are off.
                self._client = openai.OpenAI(
                    base_url=self.cfg["base_url"], api_key=self._api_key(),
                    timeout=float(self.cfg["timeout_s"]), max_retries=0,
                )
            return self._client

    def _part(self, p: Any) -> list[dict[str, Any]]:
        if isinstance(p, str):
            return [{"type": "text", "text": p}]
        if not isinstance(p, Clip):
            raise TypeError(f"unexpected message part {type(p).__name__}")
        if self.cfg["video_input"] == "video":
            return [{"type": "video_url", "video_url": {"url": mp4_data_url(p)}}]
        return [{"type": "image_url", "image_url": {"url": u}} for u in jpeg_data_urls(p, int(self.cfg["jpeg_quality"]))]

    def _payload(self, messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
        out = []
        for m in messages:
            if m["role"] == "user":
                out.append({"role": "user", "content": [x for p in m["content"] for x in self._part(p)]})
            else:  # system and assistant turns are plain text
                out.append({"role": m["role"], "content": "".join(m["content"])})
        return out

    def _generate(self, messages: list[dict[str, Any]]) -> Reply:
        import openai

        client, payload = self.client(), self._payload(messages)
        cfg = self.cfg
        where = f"{cfg['base_url']} model {cfg['model']}"
        retries, wait = int(cfg["max_retries"]), float(cfg["backoff_s"])
        what = "no request sent"  # the last fault, for the messages
        for attempt in range(retries + 1):
            left = self._time_left()
            if left is not None and left <= 0:
                raise JudgeError(f"{where}: call_deadline_s ({cfg['call_deadline_s']:g} s) passed after {attempt} "
                                 f"attempt(s), the last: {what}; raise call_deadline_s to wait longer")
            try:
                resp = client.chat.completions.create(
                    model=cfg["model"], messages=payload, temperature=0.0,
                    max_tokens=int(cfg["max_new_tokens"]), n=1,
                    extra_body=dict(cfg["extra_body"]) or None,
                    timeout=float(cfg["timeout_s"]) if left is None else min(float(cfg["timeout_s"]), left),
                )
                return _reply(resp)
            except (openai.APIConnectionError, openai.APIStatusError) as e:  # timeouts included
                status = getattr(e, "status_code", None)
                what = f"HTTP {status}" if status is not None else type(e).__name__
                transient = status is None or status in (408, 429) or status >= 500
                if not transient:
                    raise JudgeError(f"{where}: {what} after {attempt + 1} attempt(s): {e}") from e
                malformed, asked, detail = None, _retry_after_s(e), f": {e}"
            except (_Malformed, json.JSONDecodeError, openai.APIResponseValidationError) as e:
                malformed = str(e) if isinstance(e, _Malformed) else "body is not JSON"
                what, asked, detail = f"malformed reply ({malformed})", None, ""
                record_usage(malformed=1)
            if attempt == retries:
                if malformed is not None:  # the caller turns this into an invalid answer
                    raise MalformedReply(f"{where}: {what} after {attempt + 1} attempt(s)", malformed)
                raise JudgeError(f"{where}: {what} after {attempt + 1} attempt(s){detail}")
            delay = min(wait, float(cfg["backoff_max_s"]))
            if asked is not None:
                if asked > float(cfg["retry_after_max_s"]):
                    raise JudgeError(
                        f"{where}: {what}, and the server asks to retry after {asked:.0f} s, more than "
                        f"retry_after_max_s ({cfg['retry_after_max_s']:g} s); raise retry_after_max_s (and "
                        "call_deadline_s) to wait that long, or run the stage again later")
                delay = max(delay, asked)  # never back before the server asked
            left = self._time_left()
            if left is not None and delay >= left:
                raise JudgeError(f"{where}: {what}; the retry in {delay:.1f} s would pass call_deadline_s "
                                 f"({cfg['call_deadline_s']:g} s); raise call_deadline_s to wait longer")
            log.warning("%s: %s, retry %d/%d in %.1f s", self.name, what, attempt + 1, retries, delay)
            record_usage(retries=1)
            time.sleep(delay)
            wait *= 2
        raise AssertionError("unreachable")


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)

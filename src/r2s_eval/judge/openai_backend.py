"""Backend "openai": any OpenAI-compatible chat-completions server (vLLM, SGLang, a hosted API).

Video goes in as JPEG frames (``video_input: frames``) or as one H.264 video part
(``video_input: video``, which vLLM accepts for Qwen-VL models). Requests are greedy
(temperature 0) with ``max_new_tokens`` as the token limit. Connection errors, timeouts, 408, 429
and 5xx answers are retried with exponential backoff (honouring ``Retry-After``); other errors
fail at once. The API key is read from the environment variable named by ``api_key_env`` and is
never logged or stored.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from typing import Any

from r2s_eval.judge.base import register_judge
from r2s_eval.judge.frames import Clip, jpeg_data_urls, mp4_data_url
from r2s_eval.judge.usage import record_usage
from r2s_eval.judge.vlm import COMMON_DEFAULTS, Reply, VLMJudge

log = logging.getLogger(__name__)

VIDEO_INPUTS = ("frames", "video")


def _retry_after_s(err: Exception) -> float | None:
    response = getattr(err, "response", None)
    value = response.headers.get("retry-after") if response is not None else None
    try:
        return float(value) if value is not None else None
    except ValueError:
        return None


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
        "timeout_s": 600.0,
        "max_retries": 6,
        "backoff_s": 1.0,  # first wait; doubles per retry
        "backoff_max_s": 60.0,
    }
    TRANSPORT_KEYS = frozenset({"name", "base_url", "api_key_env", "timeout_s", "max_retries", "backoff_s", "backoff_max_s"})

    def __init__(self, cfg=None):
        super().__init__(cfg)
        if self.cfg["video_input"] not in VIDEO_INPUTS:
            raise ValueError(f"openai judge: video_input must be one of {VIDEO_INPUTS}, got {self.cfg['video_input']!r}")
        self._client = None
        self._lock = threading.Lock()

    def _api_key(self) -> str:
        var = self.cfg["api_key_env"]
        if not var:
            return "EMPTY"  # servers started without a key accept any
        key = os.environ.get(str(var))
        if not key:
            raise KeyError(f"judge {self.name!r}: environment variable {var} (api_key_env) is not set")
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
        retries, wait = int(self.cfg["max_retries"]), float(self.cfg["backoff_s"])
        for attempt in range(retries + 1):
            try:
                resp = client.chat.completions.create(
                    model=self.cfg["model"], messages=payload, temperature=0.0,
                    max_tokens=int(self.cfg["max_new_tokens"]), n=1,
                    extra_body=dict(self.cfg["extra_body"]) or None,
                )
                break
            except (openai.APIConnectionError, openai.APIStatusError) as e:
                status = getattr(e, "status_code", None)
                transient = status is None or status in (408, 429) or status >= 500
                if not transient or attempt == retries:
                    what = f"HTTP {status}" if status is not None else type(e).__name__
                    raise RuntimeError(f"{self.cfg['base_url']} model {self.cfg['model']}: {what} after "
                                       f"{attempt + 1} attempt(s): {e}") from e
                delay = min(max(wait, _retry_after_s(e) or 0.0), float(self.cfg["backoff_max_s"]))
                log.warning("%s: %s, retry %d/%d in %.1f s", self.name,
                            f"HTTP {status}" if status is not None else type(e).__name__, attempt + 1, retries, delay)
                record_usage(retries=1)
                time.sleep(delay)
                wait *= 2
        if not resp.choices:
            raise RuntimeError(f"{self.cfg['base_url']} model {self.cfg['model']}: reply without choices")
        usage = resp.usage
        return Reply(
            text=resp.choices[0].message.content or "",
            tokens_in=int(getattr(usage, "prompt_tokens", 0) or 0),
            tokens_out=int(getattr(usage, "completion_tokens", 0) or 0),
        )

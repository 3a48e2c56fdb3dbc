"""A chat-completions server on 127.0.0.1 that answers like a (very simple) video judge.

It speaks the OpenAI chat-completions wire format over real HTTP, so the ``openai`` backend is
exercised end to end. Its answers depend only on what it is shown, the way a model's would:

* describe: the mean brightness of the frames decides the outcome label (>= 0.6 successful,
  < 0.6 failed) and is quoted in the text ("brightness 0.72"); videos in the MISSING band get a
  reply without the force/effort section;
* compare (two descriptions): the successful one wins, then the brighter one; when a description
  quotes a brightness in the CONFUSING band the reply is never a letter, in the HESITANT band it
  is a sentence first and a letter once asked again;
* compare videos (one step): the brighter video wins.

Images (``image_url``) and videos (``video_url``, an mp4 data URL) are both understood.

Scripted faults: ``fail_plan`` answers the first requests with those HTTP statuses; ``faults``
(a list the test may refill at any time) answers the next requests, one item each, with:

* an HTTP status, or ``(status, headers)``, a header value may be a function called when the
  answer is sent (an HTTP-date ``Retry-After`` relative to that moment);
* ``"not_json"``: status 200 with a body that is not JSON; ``"no_choices"``: 200 without
  ``choices``; ``"empty_choices"``: an empty ``choices`` list; ``"empty_content"`` /
  ``"null_content"``: a message whose content is "" / null;
* ``"hang"``: no answer for ``hang_s`` seconds (or until ``release()``), longer than the client waits.

``hold_after`` answers that many requests and then holds every later one until ``release()`` (to
kill a client mid-stage deterministically); ``latency_s`` delays every answer. ``log`` records
each request: its status (or the fault's name), when it arrived (``t``, monotonic seconds), the
sha256 of its body, the full prompt text, its text parts in order (``texts``: (role, text)), its
image count and, per video part, the decoded frame count, rate and duration.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import re
import signal
import subprocess
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
from PIL import Image

CONFUSING = (0.45, 0.55)
HESITANT = (0.30, 0.40)
MISSING = (0.90, 0.95)
_BRIGHT_RE = re.compile(r"brightness (\d\.\d+)")


def _brightness(url: str) -> float:
    data = base64.b64decode(url.split(",", 1)[1])
    return float(np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=float).mean() / 255.0)


def _video(url: str) -> tuple[float, dict]:
    """Mean brightness of an mp4 data URL's frames, and what its container says about timing."""
    import av

    with av.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))) as container:
        stream = container.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
        meta = {"frames": len(frames), "fps": float(stream.average_rate or 0),
                "duration_s": float(stream.duration * stream.time_base) if stream.duration else None,
                "container_duration": container.duration}
    return float(np.mean([f.mean() for f in frames]) / 255.0), meta


def _in(x: float, band: tuple[float, float]) -> bool:
    return band[0] <= x < band[1]


MALFORMED = ("not_json", "no_choices", "empty_choices", "empty_content", "null_content")


def _malformed(fault: str, completion: dict) -> bytes | dict:
    if fault == "not_json":
        return b'{"id": "cmpl-x", "choices": [{"message": '  # cut short
    if fault == "no_choices":
        return {k: v for k, v in completion.items() if k != "choices"}
    if fault == "empty_choices":
        return {**completion, "choices": []}
    content = "" if fault == "empty_content" else None
    return {**completion, "choices": [{"index": 0, "finish_reason": "stop",
                                       "message": {"role": "assistant", "content": content}}]}


class ChatServer:
    def __init__(self, latency_s: float = 0.0, fail_plan: list[int] | None = None, hold_after: int | None = None,
                 faults: list | None = None, hang_s: float = 10.0):
        self.latency_s = latency_s
        self.fail_plan = list(fail_plan or [])
        self.faults = list(faults or [])
        self.hang_s = hang_s
        self.hold_after = hold_after
        self.log: list[dict] = []
        self.answered = 0
        self._lock = threading.Lock()
        self._released = threading.Event()
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):  # keep test output quiet
                pass

            def do_POST(self):
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                status, payload, headers = server.handle(self.path, body)
                blob = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
                try:
                    self.send_response(status)
                    for k, v in headers.items():
                        self.send_header(k, v() if callable(v) else v)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(blob)))
                    self.end_headers()
                    self.wfile.write(blob)
                except OSError:  # the client is gone (killed)
                    pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self._thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self) -> ChatServer:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.release()
        self.httpd.shutdown()
        self.httpd.server_close()

    def release(self) -> None:
        self._released.set()

    # ---------------------------------------------------------------- answers
    def ok_requests(self, kind: str | None = None) -> list[dict]:
        return [e for e in self.log if e["status"] == 200 and (kind is None or e["kind"] == kind)]

    def handle(self, path: str, body: bytes) -> tuple[int, dict, dict]:
        req = json.loads(body)
        text, media, texts, videos = self._flatten(req["messages"])
        kind = ("describe" if "Describe what the robot does" in text else
                "compare_videos" if media else "compare")
        entry = {"kind": kind, "sha": hashlib.sha256(body).hexdigest(), "text": text, "status": None,
                 "t": time.monotonic(),
                 "texts": texts, "n_images": sum(1 for _, _, v in media if v is None), "videos": videos,
                 "model": req.get("model"), "temperature": req.get("temperature"), "max_tokens": req.get("max_tokens")}
        with self._lock:
            self.log.append(entry)
            if self.fail_plan:
                entry["status"] = self.fail_plan.pop(0)
                return entry["status"], {"error": {"message": "scripted failure", "type": "server_error"}}, (
                    {"Retry-After": "0"} if entry["status"] == 429 else {})
            fault = self.faults.pop(0) if self.faults else None
            if isinstance(fault, (int, tuple)):
                status, headers = fault if isinstance(fault, tuple) else (fault, {})
                entry["status"] = status
                return status, {"error": {"message": "scripted failure", "type": "server_error"}}, dict(headers)
            held = fault is None and self.hold_after is not None and self.answered >= self.hold_after
            if not held and fault is None:
                self.answered += 1
        if fault == "hang":
            entry["status"] = "hang"
            self._released.wait(self.hang_s)  # the client has given up by now; what follows is lost
            return 503, {"error": {"message": "hung"}}, {}
        if held:
            self._released.wait()
            entry["status"] = "held"
            return 503, {"error": {"message": "held"}}, {}
        if path.rstrip("/") != "/v1/chat/completions":
            entry["status"] = 404
            return 404, {"error": {"message": f"no route {path}"}}, {}
        time.sleep(self.latency_s)
        reply = self._answer(kind, text, media, req["messages"])
        completion = {
            "id": "cmpl-" + entry["sha"][:12], "object": "chat.completion", "created": 0, "model": req.get("model"),
            "choices": [{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": reply}}],
            "usage": {"prompt_tokens": len(text.split()) + 10 * len(media) + sum(v["frames"] for v in videos),
                      "completion_tokens": len(reply.split()),
                      "total_tokens": 0},
        }
        if fault in MALFORMED:
            entry["status"] = fault
            return 200, _malformed(fault, completion), {}
        if fault is not None:
            raise ValueError(f"unknown scripted fault {fault!r}")
        entry["status"] = 200
        return 200, completion, {}

    @staticmethod
    def _flatten(messages: list[dict]) -> tuple[str, list[tuple[int, float, dict | None]], list, list]:
        """All text (system, user, assistant); every image or video part as (text length before it,
        mean brightness, video timing or None for an image); the text parts as (role, text); the
        video parts' timing."""
        text, media, texts, videos = "", [], [], []
        for m in messages:
            content = m["content"]
            if isinstance(content, str):
                text += content + "\n"
                texts.append((m["role"], content))
                continue
            for part in content:
                if part["type"] == "text":
                    text += part["text"]
                    texts.append((m["role"], part["text"]))
                elif part["type"] == "image_url":
                    media.append((len(text), _brightness(part["image_url"]["url"]), None))
                elif part["type"] == "video_url":
                    b, meta = _video(part["video_url"]["url"])
                    media.append((len(text), b, meta))
                    videos.append(meta)
            text += "\n"
        return text, media, texts, videos

    def _answer(self, kind: str, text: str, media: list[tuple[int, float, dict | None]], messages: list[dict]) -> str:
        if kind == "describe":
            b = float(np.mean([x for _, x, _ in media]))
            label = "successful" if b >= 0.6 else "failed"
            parts = [
                f"**Motion smoothness:** steady, brightness {b:.3f}.",
                "**Action continuity:** no pauses.",
                f"**Task success:** {label}. The object {'ends' if b >= 0.6 else 'does not end'} in place.",
                "**Force/effort control:** gentle contact.",
                "**Summary:** a plain execution.",
            ]
            if _in(b, MISSING):
                parts.pop(3)
            return "\n".join(parts)
        if kind == "compare_videos":
            split = text.index("Rollout B:")
            a = np.mean([x for pos, x, _ in media if pos < split])
            b = np.mean([x for pos, x, _ in media if pos >= split])
            return "A" if a >= b else "B"
        # compare two descriptions
        a_text = text[text.index("Rollout A:"): text.index("Rollout B:")]
        b_text = text[text.index("Rollout B:"):]
        (ba,), (bb,) = (map(float, _BRIGHT_RE.findall(t)[:1]) for t in (a_text, b_text))
        reasked = any(m["role"] == "assistant" for m in messages)
        if _in(ba, CONFUSING) or _in(bb, CONFUSING):
            return "They look about the same to me."
        if (_in(ba, HESITANT) or _in(bb, HESITANT)) and not reasked:
            return "Rollout A is somewhat better than rollout B, I think."
        sa, sb = ("Task success: successful" in a_text), ("Task success: successful" in b_text)
        if sa != sb:
            return "A" if sa else "B"
        return "**A**" if ba >= bb else "B."


def kill_when_hanging(proc: subprocess.Popen, server: ChatServer, cache: Path, stored: int, requests: int,
                      timeout_s: float = 60.0) -> None:
    """SIGKILL `proc`, a describe run against `server` (held with `hold_after`), once `stored`
    answers are in `cache` and the server has seen `requests` requests: the later ones hang there."""
    deadline = time.time() + timeout_s
    while len(list((cache / "describe").glob("*/*.json"))) < stored or len(server.log) < requests:
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert time.time() < deadline, "the stage never got going"
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()

"""The annotation web app: a page, a small JSON API, and the set's videos under their tokens.

What leaves the server is blind: the page, the API and the video URLs carry the instruction, the
two videos' opaque tokens and frame rates, the annotator's own progress and answers, and nothing
else (no policy, outcome, episode id, task/init or item id). Only the files of the annotation set
are served, looked up by token in the set's own table, so no request path reaches any other
file. Videos are answered with aiohttp's ``FileResponse``, which honours HTTP Range requests (a
browser needs them to seek and replay an mp4).

By default the server listens on 127.0.0.1 only and answers only requests addressed to a local
host name (a web page elsewhere cannot reach it through DNS rebinding).
"""

from __future__ import annotations

import json
import logging
from importlib import resources
from pathlib import Path

import pandas as pd
from aiohttp import web

from r2s_eval.annotate.criteria import CRITERIA_TEXT, QUESTION
from r2s_eval.annotate.answers import AnnotationError, AnswerStore

log = logging.getLogger("r2s_eval.annotate")

STATIC = {"app.js": "text/javascript", "app.css": "text/css"}
LOCAL_HOSTS = ("127.0.0.1", "localhost", "[::1]")
_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; media-src 'self'; object-src 'none'; "
                               "frame-ancestors 'none'",
}


def _static(name: str) -> bytes:
    return resources.files("r2s_eval.annotate").joinpath("static", name).read_bytes()


def _json(data, status: int = 200) -> web.Response:
    return web.json_response(data, status=status, headers={"Cache-Control": "no-store"})


def _host_name(host: str | None) -> str:
    """The name part of a Host header: "127.0.0.1:8765" -> "127.0.0.1", "[::1]:8765" -> "[::1]"."""
    host = (host or "").strip().lower()
    if host.startswith("["):
        return host[: host.find("]") + 1] if "]" in host else host
    return host.split(":", 1)[0]


def make_app(store: AnswerStore, videos_dir: str | Path, *, allowed_hosts: tuple[str, ...] | None = LOCAL_HOSTS
             ) -> web.Application:
    """The app for one annotation set. ``allowed_hosts``: the Host header names it answers
    (None: any, for a server deliberately opened to a network)."""
    videos_dir = Path(videos_dir)
    items = store.items
    tokens = set(items["video_a"].astype(str)) | set(items["video_b"].astype(str))
    missing = sorted(t for t in tokens if not (videos_dir / t).is_file())
    if missing:
        raise AnnotationError(f"{videos_dir} lacks the set's videos {missing[:5]}; rebuild the annotation set")
    video_files = {t: videos_dir / t for t in tokens}  # the only files served besides the page

    @web.middleware
    async def guard(request: web.Request, handler):
        if allowed_hosts is not None and _host_name(request.host) not in allowed_hosts:
            return web.Response(status=421, text="this server answers local requests only")
        try:
            response = await handler(request)
        except AnnotationError as err:
            response = _json({"error": str(err)}, status=400)
        response.headers.update(_HEADERS)
        return response

    async def page(request: web.Request) -> web.Response:
        return web.Response(body=_static("index.html"), content_type="text/html", charset="utf-8",
                            headers={"Cache-Control": "no-store"})

    async def static(request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC:
            raise web.HTTPNotFound()
        return web.Response(body=_static(name), content_type=STATIC[name], headers={"Cache-Control": "no-store"})

    async def video(request: web.Request) -> web.StreamResponse:
        path = video_files.get(request.match_info["token"])
        if path is None:
            raise web.HTTPNotFound()
        return web.FileResponse(path, headers={"Cache-Control": "private, max-age=3600"})

    async def info(request: web.Request) -> web.Response:
        return _json({"total": len(items), "question": QUESTION,
                      "criteria": [{"name": name, "text": text} for name, text in CRITERIA_TEXT.values()]})

    async def progress(request: web.Request) -> web.Response:
        return _json(store.progress(request.query.get("annotator", "")))

    def item_payload(annotator: str, position: int) -> dict:
        row = store.item_at(annotator, position)
        answers = store.answers(annotator)
        previous = answers.loc[answers["item_id"] == row["item_id"], "choice"]
        return {"position": int(position), "total": len(items), "answered": len(answers),
                "instruction": str(row["instruction"]),
                "video_a": f"/video/{row['video_a']}", "video_b": f"/video/{row['video_b']}",
                "fps_a": float(row["fps_a"]), "fps_b": float(row["fps_b"]),
                "choice": str(previous.iloc[0]) if len(previous) else None}

    async def item(request: web.Request) -> web.Response:
        try:
            position = int(request.query.get("position", ""))
        except ValueError:
            raise AnnotationError("position must be an integer") from None
        return _json(item_payload(request.query.get("annotator", ""), position))

    async def answer(request: web.Request) -> web.Response:
        try:
            body = await request.json()
            annotator, position = str(body["annotator"]), int(body["position"])
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            raise AnnotationError("an answer is JSON with annotator, position and choice") from None
        row = store.item_at(annotator, position)
        seconds = body.get("seconds")
        store.record(annotator, str(row["item_id"]), str(body.get("choice", "")),
                     seconds=float(seconds) if isinstance(seconds, (int, float)) else None,
                     watched_full=bool(body.get("watched_full", False)))
        return _json({**store.progress(annotator), "saved": int(position)})

    app = web.Application(middlewares=[guard], client_max_size=64 * 1024)
    app.add_routes([
        web.get("/", page),
        web.get("/static/{name}", static),
        web.get(r"/video/{token:[0-9a-f]{20}\.mp4}", video),
        web.get("/api/info", info),
        web.get("/api/progress", progress),
        web.get("/api/item", item),
        web.post("/api/answer", answer),
    ])
    return app


def load_set(set_dir: str | Path) -> pd.DataFrame:
    """The key table of an annotation set folder (``set.parquet`` beside ``videos/``)."""
    path = Path(set_dir) / "set.parquet"
    if not path.is_file():
        raise AnnotationError(f"{path} does not exist: build it with `snakemake results/annotate/set.parquet`")
    return pd.read_parquet(path)


def serve(set_dir: str | Path, db: str | Path, *, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Serve the annotation page for the set in ``set_dir`` until interrupted."""
    store = AnswerStore(db, load_set(set_dir))
    local = host in ("127.0.0.1", "localhost", "::1")
    app = make_app(store, Path(set_dir) / "videos", allowed_hosts=LOCAL_HOSTS if local else None)
    shown = f"[{host}]" if ":" in host else host
    print(f"annotation page: http://{shown}:{port}/  ({len(store.items)} pairs; answers in {store.path})", flush=True)
    if not local:
        print(f"listening on {host}: anyone who can reach this address can open the page and answer", flush=True)
    try:
        web.run_app(app, host=host, port=port, print=None, access_log=None)
    finally:
        store.close()

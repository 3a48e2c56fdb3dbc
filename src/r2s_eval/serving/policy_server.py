"""Serve a `ChunkPolicy` over the openpi websocket protocol.

Any openpi client works unchanged: on connect the server sends its metadata, then answers each
msgpack observation with `{"actions": (T, action_dim) float32, "server_timing": {...}}`.
`GET /healthz` answers 200. Errors are sent as a text frame, then the connection closes with
code 1011 (internal error); other connections keep being served.

Each connection is one episode slot: the policy's per-episode state (observation history,
seeded noise) lives under that connection's slot id.

Extension (not in openpi; announced by `"supports_reset": True` in the metadata): the message
`{"r2s_eval": "reset", "seed": <int>}` starts a new episode in the connection's slot
(`policy.reset(slot, seed)`) and is answered `{"ok": True}`. openpi clients never send it.
"""

from __future__ import annotations

import asyncio
import hmac
import http
import itertools
import json
import logging
import signal
import threading
import time
from collections.abc import Callable

import numpy as np
from websockets.asyncio.server import ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

import r2s_eval
from r2s_eval.policies.interface import ChunkPolicy, PolicyError
from r2s_eval.serving.protocol import DEFAULT_MAX_MESSAGE_BYTES, ProtocolError, pack, unpack_dict

log = logging.getLogger(__name__)

RESET_KEY = "r2s_eval"
HEALTH_PATH = "/healthz"
INTERNAL_ERROR = 1011
MAX_ERROR_CHARS = 2000


def _plain(value):
    # Metadata goes to foreign clients: JSON-safe values only (paths and the like as text).
    return json.loads(json.dumps(value, default=str))


def ws_url(host: str, port: int) -> str:
    return f"ws://[{host}]:{port}" if ":" in host else f"ws://{host}:{port}"


class PolicyServer:
    def __init__(self, policy: ChunkPolicy, host: str = "127.0.0.1", port: int = 0,
                 api_key: str | None = None, max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 close_timeout_s: float = 5.0):
        self.policy = policy
        self.host = host
        self.port = port
        self._api_key = api_key
        self.max_message_bytes = int(max_message_bytes)
        self.close_timeout_s = close_timeout_s
        self.metadata = _plain({
            "server": "r2s-eval",
            "version": r2s_eval.__version__,
            "policy": policy.metadata(),
            "spec": policy.spec.to_dict(),
            "supports_reset": True,
        })
        self._model_lock = threading.Lock()  # one shared model: calls never overlap
        self._slot_ids = itertools.count()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._thread: threading.Thread | None = None

    # -- HTTP side of the handshake ------------------------------------------------------------
    def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        if request.path == HEALTH_PATH:
            return connection.respond(http.HTTPStatus.OK, "ok\n")
        if self._api_key is not None:
            given = request.headers.get("Authorization", "")
            # Constant-time comparison: the key must not leak through response timing.
            if not hmac.compare_digest(given.encode(), f"Api-Key {self._api_key}".encode()):
                log.warning("refused %s: missing or wrong API key", connection.remote_address)
                return connection.respond(http.HTTPStatus.UNAUTHORIZED, "missing or wrong API key\n")
        return None

    # -- one connection = one episode slot -----------------------------------------------------
    def _locked(self, fn: Callable, *args):
        with self._model_lock:
            return fn(*args)

    def _infer(self, slot: int, obs: dict) -> dict:
        selected = self.policy.select(obs)  # names missing or malformed streams
        with self._model_lock:
            t0 = time.perf_counter()  # the model's time, not the wait for the lock
            self.policy.observe(slot, obs)
            chunk = np.asarray(self.policy.predict_chunks([slot], [selected])[0], dtype=np.float32)
        infer_ms = 1000.0 * (time.perf_counter() - t0)
        if chunk.ndim != 2 or chunk.shape[1] != self.policy.spec.action_dim:
            raise PolicyError(f"policy {self.policy.name!r} returned a chunk of shape {chunk.shape}")
        return {"actions": chunk, "server_timing": {"infer_ms": infer_ms}}

    async def _reply(self, slot: int, message) -> dict:
        if isinstance(message, str):
            raise ProtocolError("expected a binary msgpack message, got a text frame")
        msg = unpack_dict(message, self.max_message_bytes)
        if RESET_KEY in msg:
            seed = msg.get("seed")
            if msg[RESET_KEY] != "reset" or isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
                raise ProtocolError(f'unknown extension message; expected {{"{RESET_KEY}": "reset", "seed": <int>}}')
            await asyncio.to_thread(self._locked, self.policy.reset, slot, int(seed))
            return {"ok": True}
        # Inference in a worker thread: the event loop keeps answering pings and other clients.
        return await asyncio.to_thread(self._infer, slot, msg)

    async def _handler(self, ws: ServerConnection) -> None:
        slot = next(self._slot_ids)
        peer = ws.remote_address
        log.info("slot %d: connected from %s", slot, peer)
        try:
            # A fresh connection is a fresh episode, also for clients that never send a reset.
            await asyncio.to_thread(self._locked, self.policy.reset, slot, 0)
            await ws.send(pack(self.metadata))
            async for message in ws:
                await ws.send(pack(await self._reply(slot, message)))
        except ConnectionClosed:
            pass
        except Exception as exc:
            if isinstance(exc, (PolicyError, ProtocolError)):  # the client's doing: no traceback
                log.warning("slot %d (%s): %s", slot, peer, exc)
            else:
                log.exception("slot %d (%s): error", slot, peer)
            text = f"{type(exc).__name__}: {exc}"[:MAX_ERROR_CHARS]
            try:
                await ws.send(text)  # openpi clients raise on a text frame
                await ws.close(INTERNAL_ERROR, type(exc).__name__[:100])
            except ConnectionClosed:
                pass
        finally:
            self.policy.release(slot)
            log.info("slot %d: disconnected (%s)", slot, ws.close_code)

    # -- running ------------------------------------------------------------------------------
    async def _main(self, on_ready: Callable[[int], None] | None) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        async with serve(
            self._handler, self.host, self.port,
            process_request=self._process_request,
            max_size=self.max_message_bytes,
            compression=None,  # images hardly compress; deflate would only cost CPU
            close_timeout=self.close_timeout_s,
        ) as server:
            self.port = server.sockets[0].getsockname()[1]
            log.info("serving %r on %s", self.policy.name, ws_url(self.host, self.port))
            if on_ready is not None:
                on_ready(self.port)
            await self._stop.wait()

    def serve_forever(self, on_ready: Callable[[int], None] | None = None) -> None:
        """Serve until SIGINT/SIGTERM (main thread) or `stop()`; `on_ready(port)` once bound."""

        async def main():
            if threading.current_thread() is threading.main_thread():
                loop = asyncio.get_running_loop()
                for sig in (signal.SIGINT, signal.SIGTERM):
                    loop.add_signal_handler(sig, lambda: self._stop.set() if self._stop else None)
            await self._main(on_ready)

        asyncio.run(main())

    def start(self, timeout_s: float = 30.0) -> int:
        """Serve from a background thread; returns the bound port."""
        ready = threading.Event()
        failure: list[BaseException] = []

        def run():
            try:
                asyncio.run(self._main(lambda _port: ready.set()))
            except BaseException as exc:  # reported to the caller of start()
                failure.append(exc)
                ready.set()

        self._thread = threading.Thread(target=run, name="policy-server", daemon=True)
        self._thread.start()
        if not ready.wait(timeout_s):
            raise TimeoutError(f"policy server did not start within {timeout_s}s")
        if failure:
            raise failure[0]
        return self.port

    def stop(self, timeout_s: float = 10.0) -> None:
        if self._loop is not None and self._stop is not None and not self._loop.is_closed():
            try:
                self._loop.call_soon_threadsafe(self._stop.set)
            except RuntimeError:  # loop already finished
                pass
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

"""Helpers of the serving tests: observations, a fake policy, a misbehaving openpi server."""

from __future__ import annotations

import asyncio
import http
import socket
import threading
import time

import numpy as np
from websockets.asyncio.server import serve
from websockets.exceptions import ConnectionClosed

from r2s_eval.policies.interface import ChunkPolicy, PolicySpec
from r2s_eval.serving.protocol import pack, unpack_dict

HEAD = "observation.images.head_left"
STATE = "observation.state"
SPEC = PolicySpec(cameras=(HEAD,), action_dim=14, max_chunk=25, uses_state=True, state_dim=14)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def observation(seed: int = 0, hw: tuple[int, int] = (32, 32)) -> dict:
    rng = np.random.default_rng(seed)
    return {
        STATE: rng.normal(0, 0.1, size=14).astype(np.float32),
        HEAD: rng.integers(0, 255, size=(*hw, 3), dtype=np.uint8),
        "task": "pick the cube",
    }


class FakePolicy(ChunkPolicy):
    """Actions = the slot's seed + state[0]: shows which episode state the server used.

    Counts concurrent model calls, to check that the server serialises them.
    """

    name = "fake"

    def __init__(self, delay_s: float = 0.0):
        self.spec = SPEC
        self.delay_s = delay_s
        self.seeds: dict[int, int] = {}
        self.observed: list[int] = []
        self.active = self.max_active = self.calls = 0
        self._lock = threading.Lock()

    def reset(self, slot, seed):
        self.seeds[slot] = seed

    def observe(self, slot, obs):
        self.observed.append(slot)

    def predict_chunks(self, slots, observations):
        with self._lock:
            self.active += 1
            self.calls += 1
            self.max_active = max(self.max_active, self.active)
        time.sleep(self.delay_s)
        with self._lock:
            self.active -= 1
        return np.stack([
            np.full((25, 14), self.seeds.get(s, -1) + float(o[STATE][0]), np.float32)
            for s, o in zip(slots, observations)
        ])


class ThreadedServer:
    """A websocket server on a thread of its own, on a free port (`port`), for `with` blocks.
    Subclasses give `_handler`, and may give `_process_request` (the handshake) and
    `compression` (websockets' default: permessage-deflate offered)."""

    _process_request = None
    compression = "deflate"

    def __init__(self):
        self.port = 0
        self._ready = threading.Event()

    async def _main(self):
        self._stop = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        async with serve(self._handler, "127.0.0.1", 0, process_request=self._process_request,
                         compression=self.compression, close_timeout=1) as server:
            self.port = server.sockets[0].getsockname()[1]
            self._ready.set()
            await self._stop.wait()

    def __enter__(self):
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self._thread.start()
        assert self._ready.wait(10), f"{type(self).__name__} did not start"
        return self

    def __exit__(self, *exc) -> None:
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)


class FaultServer(ThreadedServer):
    """An openpi-style server that sends our metadata, then misbehaves as `behaviour` says.

    good: correct replies; refuse: HTTP 403 at the handshake; wrong_shape: (25, 7) actions;
    nan: non-finite actions; text: an error text frame, then close 1011; die_after_first: one
    good reply, then the connection closes; crash_after_first: one good reply, then the TCP
    connection drops without a close frame; silent: never replies to observations.
    """

    def __init__(self, behaviour: str):
        super().__init__()
        self.behaviour = behaviour
        self.connections = 0

    def _process_request(self, connection, request):
        if self.behaviour == "refuse":
            return connection.respond(http.HTTPStatus.FORBIDDEN, "forbidden\n")
        return None

    async def _handler(self, ws):
        self.connections += 1
        await ws.send(pack({"server": "fault", "spec": SPEC.to_dict(), "supports_reset": True,
                            "policy": {"name": "fault"}}))
        good = {"actions": np.zeros((25, 14), np.float32), "server_timing": {"infer_ms": 0.0}}
        n = 0
        try:
            async for message in ws:
                msg = unpack_dict(message)
                if "r2s_eval" in msg:
                    await ws.send(pack({"ok": True}))
                    continue
                n += 1
                if self.behaviour in ("good", "die_after_first", "crash_after_first"):
                    await ws.send(pack(good))
                    if self.behaviour == "die_after_first":  # a clean shutdown
                        await ws.close(1001, "going away")
                        return
                    if self.behaviour == "crash_after_first":  # the process dies: no close frame
                        await asyncio.sleep(0.1)  # let the reply leave first
                        ws.transport.abort()
                        return
                elif self.behaviour == "wrong_shape":
                    await ws.send(pack({"actions": np.zeros((25, 7), np.float32)}))
                elif self.behaviour == "nan":
                    actions = np.zeros((25, 14), np.float32)
                    actions[3, 2] = np.nan
                    await ws.send(pack({"actions": actions}))
                elif self.behaviour == "text":
                    await ws.send("RuntimeError: model exploded")
                    await ws.close(1011, "RuntimeError")
                    return
                # silent: read and never answer
        except ConnectionClosed:
            pass

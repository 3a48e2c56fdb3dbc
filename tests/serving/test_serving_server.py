"""PolicyServer in-process with a fake policy: metadata, slots, reset, locking, errors, limits."""

from __future__ import annotations

import http.client
import threading
import time

import numpy as np
import pytest
from openpi_client.websocket_client_policy import WebsocketClientPolicy
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from r2s_eval import __version__
from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import PolicyError, RecedingHorizon
from r2s_eval.serving import PolicyServer, ServerPolicy
from r2s_eval.serving.protocol import pack, unpack_dict

pytestmark = [
    pytest.mark.timeout(60),
    # openpi-client opens its connection in a form websockets 17 deprecates.
    pytest.mark.filterwarnings("ignore:connect\\(\\) must be used as a context manager:DeprecationWarning"),
]


@pytest.fixture
def server(helpers, request):
    delay_s, max_bytes = getattr(request, "param", (0.0, 1 << 20))
    srv = PolicyServer(helpers.FakePolicy(delay_s=delay_s), max_message_bytes=max_bytes)
    srv.start()
    yield srv
    srv.stop()


def _healthz(port: int) -> tuple[int, str]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        conn.request("GET", "/healthz")
        resp = conn.getresponse()
        return resp.status, resp.read().decode()
    finally:
        conn.close()


def test_serving_server_metadata_slots_and_reset(server, helpers):
    assert _healthz(server.port) == (200, "ok\n")
    client = WebsocketClientPolicy("127.0.0.1", server.port)
    meta = client.get_server_metadata()
    assert meta["server"] == "r2s-eval" and meta["version"] == __version__ and meta["supports_reset"] is True
    assert meta["spec"] == helpers.SPEC.to_dict() and meta["policy"]["name"] == "fake"
    obs = helpers.observation(1)
    reply = client.infer(obs)
    # A connection that never resets is an episode seeded 0.
    np.testing.assert_allclose(reply["actions"], np.full((25, 14), obs["observation.state"][0]), rtol=1e-6)
    assert reply["actions"].dtype == np.float32 and reply["server_timing"]["infer_ms"] >= 0

    # ServerPolicy: one connection per slot, so each slot's reset reaches its own server slot.
    policy = ServerPolicy("fake", "127.0.0.1", server.port)
    try:
        assert policy.spec == helpers.SPEC
        policy.reset(0, 100)
        policy.reset(1, 200)
        chunks = policy.predict_chunks([0, 1], [obs, obs])
        assert chunks.shape == (2, 25, 14) and chunks.dtype == np.float32
        np.testing.assert_allclose(chunks[:, 0, 0], np.array([100, 200]) + obs["observation.state"][0], rtol=1e-6)
        assert sorted(server.policy.seeds.values())[-2:] == [100, 200]
        meta = policy.metadata()
        assert meta["name"] == "fake" and meta["served"]["name"] == "fake"
        assert str(server.port) not in repr(meta) and "127.0.0.1" not in repr(meta)
    finally:
        policy.close()


def test_serving_server_receding_horizon_model_calls(server, helpers):
    policy = ServerPolicy("fake", "127.0.0.1", server.port)
    try:
        runner = RecedingHorizon(policy, Horizon(25, 5), seed=3)
        actions = [runner.act(helpers.observation(t)) for t in range(12)]
        assert all(a.shape == (14,) for a in actions)
        assert runner.stats["model_calls"] == 3 == server.policy.calls
    finally:
        policy.close()


@pytest.mark.parametrize("server", [(0.4, 1 << 20)], indirect=True)
def test_serving_server_serialises_model_and_stays_responsive(server, helpers):
    results, errors = [], []

    def one_client():
        try:
            results.append(WebsocketClientPolicy("127.0.0.1", server.port).infer(helpers.observation()))
        except Exception as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=one_client) for _ in range(3)]
    for t in threads:
        t.start()
    time.sleep(0.2)  # a model call is in progress: the event loop must still answer
    t0 = time.perf_counter()
    assert _healthz(server.port)[0] == 200
    assert time.perf_counter() - t0 < 0.3
    for t in threads:
        t.join(10)
    assert not errors and len(results) == 3
    assert server.policy.max_active == 1


def test_serving_server_error_closes_one_connection_only(server, helpers):
    bad = WebsocketClientPolicy("127.0.0.1", server.port)
    with pytest.raises(RuntimeError, match="observation.images.head_left"):
        bad.infer({"observation.state": np.zeros(14, np.float32)})
    # A raw client sees the text frame, then close code 1011.
    with connect(f"ws://127.0.0.1:{server.port}", compression=None) as ws:
        ws.recv(timeout=5)
        ws.send(b"\xc1 not msgpack")
        text = ws.recv(timeout=5)
        assert isinstance(text, str) and "ProtocolError" in text and "msgpack" in text
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5)
        assert closed.value.rcvd.code == 1011
    with connect(f"ws://127.0.0.1:{server.port}", compression=None) as ws:
        ws.recv(timeout=5)
        ws.send(pack({"r2s_eval": "reset", "seed": "x"}))
        assert "seed" in ws.recv(timeout=5)
    # ... and the server goes on serving.
    good = WebsocketClientPolicy("127.0.0.1", server.port)
    assert good.infer(helpers.observation())["actions"].shape == (25, 14)
    with connect(f"ws://127.0.0.1:{server.port}", compression=None) as ws:
        ws.recv(timeout=5)
        ws.send(pack({"r2s_eval": "reset", "seed": 5}))
        assert unpack_dict(ws.recv(timeout=5)) == {"ok": True}


@pytest.mark.parametrize("server", [(0.0, 100_000)], indirect=True)
def test_serving_server_bounds_message_size(server, helpers):
    big = helpers.observation(hw=(256, 256))  # ~200 kB of image
    client = WebsocketClientPolicy("127.0.0.1", server.port)
    with pytest.raises(ConnectionClosed) as closed:
        client.infer(big)
    assert closed.value.rcvd.code == 1009  # message too big
    policy = ServerPolicy("fake", "127.0.0.1", server.port)
    try:
        with pytest.raises(PolicyError, match=rf"'fake' at 127.0.0.1:{server.port}"):
            policy.predict_chunks([0], [big])
        policy.reset(0, 0)  # the slot reconnects
        assert policy.predict_chunks([0], [helpers.observation()]).shape == (1, 25, 14)
    finally:
        policy.close()


def test_serving_server_replaced_model_is_noticed(helpers):
    first = PolicyServer(helpers.FakePolicy())
    port = first.start()
    policy = ServerPolicy("fake", "127.0.0.1", port)
    try:
        policy.reset(0, 0)
        first.stop()
        other = helpers.FakePolicy()
        other.name = "other"
        second = PolicyServer(other, port=port)  # same address, another model
        second.start()
        try:
            with pytest.raises(PolicyError, match=rf"at 127\.0\.0\.1:{port}: the server now serves .*'other'"):
                policy.reset(1, 0)
        finally:
            second.stop()
    finally:
        policy.close()

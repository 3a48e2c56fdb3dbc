"""ServerPolicy against servers that are down or misbehave: every failure is a named PolicyError."""

from __future__ import annotations

import time

import numpy as np
import pytest

from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import PolicyError, RecedingHorizon
from r2s_eval.serving import ServerPolicy

pytestmark = pytest.mark.timeout(60)


def _names(port: int) -> str:
    return rf"policy 'remote' at 127\.0\.0\.1:{port}: "


def _policy(port: int, **kw) -> ServerPolicy:
    kw = {"connect_timeout_s": 3, "reply_timeout_s": 1, "connect_retries": 2, "backoff_s": 0.1, **kw}
    return ServerPolicy("remote", "127.0.0.1", port, **kw)


def test_serving_fault_server_down(helpers):
    port = helpers.free_port()  # nothing listens there
    t0 = time.perf_counter()
    with pytest.raises(PolicyError, match=_names(port) + r"connection refused \(is the server running\?\)"):
        _policy(port).spec
    assert time.perf_counter() - t0 < 3
    # A spec given up front needs no server until the first episode starts.
    policy = _policy(port, cameras=[helpers.HEAD], action_dim=14, max_chunk=25)
    assert policy.spec.max_chunk == 25
    with pytest.raises(PolicyError, match=_names(port) + "connection refused"):
        RecedingHorizon(policy, Horizon(25, 5))


def test_serving_fault_refused_at_handshake(helpers):
    with helpers.FaultServer("refuse") as srv:
        with pytest.raises(PolicyError, match=_names(srv.port) + "server refused the connection: HTTP 403"):
            _policy(srv.port).reset(0, 0)


@pytest.mark.parametrize("behaviour,match", [
    ("wrong_shape", r"actions of shape \(25, 7\), expected \(T>=1, 14\)"),
    ("nan", "non-finite actions"),
    ("text", "server error: RuntimeError: model exploded"),
    ("silent", r"no reply within 1s waiting for the actions of slot 0"),
])
def test_serving_fault_bad_replies(helpers, behaviour, match):
    with helpers.FaultServer(behaviour) as srv:
        policy = _policy(srv.port)
        try:
            runner = RecedingHorizon(policy, Horizon(25, 5))
            t0 = time.perf_counter()
            with pytest.raises(PolicyError, match=_names(srv.port) + match):
                runner.act(helpers.observation())
            assert time.perf_counter() - t0 < 5
            # The episode is over: no silent retry on the same slot...
            with pytest.raises(PolicyError, match=_names(srv.port) + "slot 0: .*reset the slot"):
                runner.act(helpers.observation())
        finally:
            policy.close()


@pytest.mark.parametrize("behaviour", ["die_after_first", "crash_after_first"])
def test_serving_fault_server_dies_mid_episode(helpers, behaviour):
    with helpers.FaultServer(behaviour) as srv:
        policy = _policy(srv.port)
        try:
            runner = RecedingHorizon(policy, Horizon(25, 5))
            for _ in range(5):  # the first chunk arrives and is executed
                assert runner.act(helpers.observation()).shape == (14,)
            with pytest.raises(PolicyError, match=_names(srv.port) + "connection closed .*slot 0"):
                runner.act(helpers.observation())
            assert srv.connections == 1  # no silent reconnect mid-episode
            with pytest.raises(PolicyError, match="reset the slot to reconnect"):
                runner.act(helpers.observation())
            # The next episode reconnects.
            runner.reset(seed=1)
            np.testing.assert_array_equal(runner.act(helpers.observation()), np.zeros(14, np.float32))
            assert srv.connections == 2
        finally:
            policy.close()


def test_serving_fault_foreign_server_without_spec(helpers):
    with helpers.FaultServer("good") as srv:
        # Constructor fields win over what the server announces.
        policy = _policy(srv.port, max_chunk=10)
        try:
            assert policy.spec.max_chunk == 10 and policy.spec.action_dim == 14
            assert policy.predict_chunks([0], [helpers.observation()]).shape == (1, 10, 14)
        finally:
            policy.close()


def test_serving_fault_missing_api_key_env(monkeypatch):
    monkeypatch.delenv("R2S_NO_SUCH_KEY", raising=False)
    with pytest.raises(PolicyError, match=r"policy 'remote' at 127\.0\.0\.1:1: environment variable R2S_NO_SUCH_KEY"):
        ServerPolicy("remote", "127.0.0.1", 1, api_key_env="R2S_NO_SUCH_KEY")

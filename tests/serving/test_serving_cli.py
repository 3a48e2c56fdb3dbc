"""`python -m r2s_eval.serve` on a tiny trained ACT checkpoint, reached by openpi-client and ServerPolicy."""

from __future__ import annotations

import http.client
import re

import numpy as np
import pytest
from openpi_client.websocket_client_policy import WebsocketClientPolicy

from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import PolicyError, RecedingHorizon
from r2s_eval.policies.lerobot_policy import load_lerobot_policy
from r2s_eval.serve import main as serve_main
from r2s_eval.serving import ServerPolicy

pytestmark = [
    pytest.mark.timeout(300),
    # openpi-client opens its connection in a form websockets 17 deprecates.
    pytest.mark.filterwarnings("ignore:connect\\(\\) must be used as a context manager:DeprecationWarning"),
]

CHUNK = 25  # every candidate config's chunk size


def test_serving_cli_healthz_and_ready_line(served):
    srv = served["open"]
    assert srv.line == f"serving act_open on ws://127.0.0.1:{srv.port}"
    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=5)
    conn.request("GET", "/healthz")
    assert conn.getresponse().status == 200
    conn.close()


def test_serving_cli_openpi_client(served, helpers, act_checkpoint):
    client = WebsocketClientPolicy("127.0.0.1", served["open"].port)
    meta = client.get_server_metadata()
    assert meta["server"] == "r2s-eval" and meta["policy"]["name"] == "act_open"
    assert meta["spec"]["action_dim"] == 14 and meta["spec"]["cameras"] == [helpers.HEAD]
    assert meta["spec"]["max_chunk"] == CHUNK
    obs = helpers.observation(3)
    reply = client.infer(obs)
    actions = reply["actions"]
    assert actions.shape == (CHUNK, 14) and actions.dtype == np.float32
    assert np.isfinite(actions).all() and reply["server_timing"]["infer_ms"] > 0
    # Served actions are the in-process policy's actions.
    local = load_lerobot_policy(act_checkpoint)
    local.reset(0, 0)
    expected = local.predict_chunks([0], [local.select(obs)])[0]
    np.testing.assert_allclose(actions, expected, rtol=1e-4, atol=1e-5)


def test_serving_cli_server_policy_receding_horizon(served, helpers):
    policy = ServerPolicy("act", "127.0.0.1", served["open"].port)
    try:
        runner = RecedingHorizon(policy, Horizon(CHUNK, 5))
        actions = [runner.act(helpers.observation(t)) for t in range(12)]
        assert all(a.shape == (14,) and np.isfinite(a).all() for a in actions)
        assert runner.stats["model_calls"] == 3
        meta = policy.metadata()
        assert meta["served"]["policy_type"] == "act" and str(served["open"].port) not in repr(meta)
    finally:
        policy.close()


def test_serving_cli_api_key(served, helpers, monkeypatch):
    srv = served["keyed"]
    where = rf"policy 'act' at 127\.0\.0\.1:{srv.port}: "
    assert srv.key not in srv.stderr()  # never logged
    # Without the key, or with a wrong one: refused at the handshake.
    with pytest.raises(PolicyError, match=where + "server refused the connection: HTTP 401"):
        ServerPolicy("act", "127.0.0.1", srv.port).spec
    monkeypatch.setenv("SERVING_TEST_WRONG_KEY", "wrong")
    with pytest.raises(PolicyError, match=where + ".*HTTP 401"):
        ServerPolicy("act", "127.0.0.1", srv.port, api_key_env="SERVING_TEST_WRONG_KEY").spec
    with pytest.raises(Exception, match="401"):
        WebsocketClientPolicy("127.0.0.1", srv.port)
    # With it: served.
    keyed = WebsocketClientPolicy("127.0.0.1", srv.port, api_key=srv.key)
    assert keyed.infer(helpers.observation())["actions"].shape == (CHUNK, 14)
    monkeypatch.setenv("SERVING_TEST_KEY", srv.key)
    policy = ServerPolicy("act", "127.0.0.1", srv.port, api_key_env="SERVING_TEST_KEY")
    try:
        assert srv.key not in repr(policy.metadata()) and srv.key not in repr(policy)
        runner = RecedingHorizon(policy, Horizon(CHUNK, 5))
        assert runner.act(helpers.observation()).shape == (14,)
    finally:
        policy.close()
    assert srv.key not in srv.stderr()


def test_serving_cli_clean_errors(tmp_path, capsys, monkeypatch):
    missing = tmp_path / "no_checkpoint"
    assert serve_main([str(missing), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"error: cannot load a policy from {re.escape(str(missing))}", err)
    assert "Traceback" not in err
    monkeypatch.delenv("SERVING_TEST_UNSET", raising=False)
    assert serve_main([str(missing), "--api-key-env", "SERVING_TEST_UNSET"]) == 2
    assert "SERVING_TEST_UNSET" in capsys.readouterr().err


def test_serving_cli_sim_episode_against_the_served_policy(served):
    # A closed-loop episode in our MuJoCo world, every chunk fetched from the subprocess server,
    # recorded exactly as the rollout stage records it.
    from r2s_eval.rollout import run_episode
    from tests.helpers.worlds import bundled_env

    env = bundled_env("cup_on_plate", image_size=(32, 32), cameras=("head_left",))
    policy = ServerPolicy("act", "127.0.0.1", served["open"].port)
    try:
        runner = RecedingHorizon(policy, Horizon(CHUNK, 5))
        runner.reset(seed=7)
        result = run_episode(env, runner, None, seed=7, max_steps=20, video_camera="head_left")
    finally:
        policy.close()
    assert result.length == 20 and len(result.frames) == 21
    assert runner.stats["model_calls"] == 4
    actions = np.stack(result.trajectory["action"].to_list())
    assert actions.shape == (20, 14) and np.isfinite(actions).all()

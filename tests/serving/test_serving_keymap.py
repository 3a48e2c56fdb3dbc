"""Peer-protocol key maps: each openpi preset against a server that accepts only its example
client's keys, shapes and dtypes; overrides; unfilled keys and missing streams; no map = as before."""

from __future__ import annotations

import traceback

import numpy as np
import pytest
from openpi_client import image_tools
from openpi_client.websocket_client_policy import WebsocketClientPolicy
from websockets.exceptions import ConnectionClosed

from r2s_eval.horizon import Horizon
from r2s_eval.policies.interface import PolicyError, RecedingHorizon
from r2s_eval.serving import PolicyServer, ServerPolicy
from r2s_eval.serving.keymap import PRESETS, resize_with_pad, resolve_key_map
from r2s_eval.serving.protocol import pack, unpack_dict

from tests.helpers.policy_server import ThreadedServer

pytestmark = [
    pytest.mark.timeout(60),
    pytest.mark.filterwarnings("ignore:connect\\(\\) must be used as a context manager:DeprecationWarning"),
]

IMG = "observation.images."
STATE = "observation.state"

# What openpi's example clients send (examples/libero/main.py, examples/droid/main.py): key ->
# (shape, dtype), or str for the prompt. A strict server accepts exactly these.
OPENPI_LIBERO = {
    "observation/image": ((224, 224, 3), np.uint8),
    "observation/wrist_image": ((224, 224, 3), np.uint8),
    "observation/state": ((8,), np.float64),
    "prompt": str,
}
OPENPI_DROID = {
    "observation/exterior_image_1_left": ((224, 224, 3), np.uint8),
    "observation/wrist_image_left": ((224, 224, 3), np.uint8),
    "observation/joint_position": ((7,), np.float64),
    "observation/gripper_position": ((1,), np.float64),
    "prompt": str,
}


class PeerServer(ThreadedServer):
    """An openpi-style server (metadata without a spec, no reset extension): with `accepts`, any
    request whose keys, shapes or dtypes differ is answered, as openpi's server does, with the
    traceback as a text frame and close code 1011. Records every request (raw and decoded)."""

    compression = None

    def __init__(self, accepts: dict | None, action_dim: int, chunk: int = 10):
        super().__init__()
        self.accepts, self.action_dim, self.chunk = accepts, action_dim, chunk
        self.raw: list[bytes] = []
        self.requests: list[dict] = []

    def actions(self) -> np.ndarray:  # float64, as a numpy policy may return: the client casts
        return np.arange(self.chunk * self.action_dim, dtype=np.float64).reshape(self.chunk, self.action_dim) / 100

    def _check(self, msg: dict) -> None:
        if set(msg) != set(self.accepts):
            raise KeyError(f"unexpected keys: got {sorted(msg)}, expected {sorted(self.accepts)}")
        for key, want in self.accepts.items():
            value = msg[key]
            if want is str:
                if not isinstance(value, str):
                    raise TypeError(f"{key}: expected a string, got {type(value).__name__}")
                continue
            shape, dtype = want
            if not isinstance(value, np.ndarray) or value.shape != shape or value.dtype != dtype:
                got = (value.shape, value.dtype) if isinstance(value, np.ndarray) else type(value).__name__
                raise ValueError(f"{key}: expected {shape} {np.dtype(dtype)}, got {got}")

    async def _handler(self, ws):
        await ws.send(pack({"policy_name": "peer"}))
        try:
            async for message in ws:
                self.raw.append(bytes(message))
                try:
                    msg = unpack_dict(message)
                    self.requests.append(msg)
                    if self.accepts is not None:
                        self._check(msg)
                except Exception:
                    await ws.send(traceback.format_exc())
                    await ws.close(1011, "Internal server error")
                    return
                await ws.send(pack({"actions": self.actions(), "server_timing": {"infer_ms": 1.0}}))
        except ConnectionClosed:
            pass


def _image(rng, hw=(256, 256)) -> np.ndarray:
    return rng.integers(0, 255, size=(*hw, 3), dtype=np.uint8)


def libero_observation(seed: int = 0) -> dict:
    """What our LIBERO world sends (libero.observation.cameras, 256x256, 8-D float32 state)."""
    rng = np.random.default_rng(seed)
    return {IMG + "image": _image(rng), IMG + "image2": _image(rng), IMG + "wrist_image": _image(rng),
            STATE: rng.normal(size=8).astype(np.float32), "task": "put the bowl on the plate"}


def panda_observation(seed: int = 0) -> dict:
    """What our panda world sends (cameras head_left, front, wrist at 128x128; 7 joints + gripper)."""
    rng = np.random.default_rng(seed)
    return {IMG + "head_left": _image(rng, (128, 128)), IMG + "front": _image(rng, (128, 160)),
            IMG + "wrist": _image(rng, (128, 128)), STATE: rng.normal(size=8).astype(np.float32),
            "task": "put the block on the plate"}


DROID_CAMERAS = {"observation/exterior_image_1_left": {"camera": "front"},
                 "observation/wrist_image_left": {"camera": "wrist"}}


def test_keymap_libero_preset_is_accepted_by_a_strict_openpi_libero_server():
    obs = libero_observation()
    with PeerServer(OPENPI_LIBERO, action_dim=7) as peer:
        policy = ServerPolicy("pi05_openpi", "127.0.0.1", peer.port, preset="openpi_libero", max_chunk=10)
        try:
            # Preset + max_chunk is a whole spec: nothing is asked of the server to know it.
            assert policy.spec.cameras == (IMG + "image", IMG + "wrist_image")
            assert (policy.spec.action_dim, policy.spec.uses_state, policy.spec.uses_task) == (7, True, True)
            policy.reset(0, seed=3)
            chunks = policy.predict_chunks([0], [policy.select(obs)])
        finally:
            policy.close()
    (sent,) = peer.requests
    # openpi's LIBERO client: resize_with_pad to 224 + convert_to_uint8, the state, the prompt.
    for key, ours in (("observation/image", "image"), ("observation/wrist_image", "wrist_image")):
        expected = image_tools.convert_to_uint8(image_tools.resize_with_pad(obs[IMG + ours], 224, 224))
        np.testing.assert_array_equal(sent[key], expected)
    np.testing.assert_array_equal(sent["observation/state"], obs[STATE].astype(np.float64))
    assert sent["prompt"] == "put the bowl on the plate"
    # The reply's actions come back as our (batch, T, 7) float32 chunk.
    assert chunks.shape == (1, 10, 7) and chunks.dtype == np.float32
    np.testing.assert_allclose(chunks[0], peer.actions(), rtol=1e-6)


def test_keymap_droid_preset_is_accepted_by_a_strict_openpi_droid_server():
    obs = panda_observation()
    with PeerServer(OPENPI_DROID, action_dim=8, chunk=15) as peer:
        policy = ServerPolicy("pi05_droid", "127.0.0.1", peer.port, preset="openpi_droid",
                              keys=DROID_CAMERAS, max_chunk=15)
        try:
            horizon = RecedingHorizon(policy, Horizon(10, 4))  # the evaluation's loop
            actions = [horizon.act(panda_observation(seed)) for seed in range(5)]
        finally:
            policy.close()
    assert len(peer.requests) == 2  # 4 actions per chunk: a second query at the fifth step
    sent = peer.requests[0]
    np.testing.assert_array_equal(sent["observation/exterior_image_1_left"],
                                  image_tools.resize_with_pad(obs[IMG + "front"], 224, 224))  # 128x160: padded
    np.testing.assert_array_equal(sent["observation/wrist_image_left"],
                                  image_tools.resize_with_pad(obs[IMG + "wrist"], 224, 224))
    np.testing.assert_array_equal(sent["observation/joint_position"], obs[STATE][:7].astype(np.float64))
    np.testing.assert_array_equal(sent["observation/gripper_position"], obs[STATE][7:8].astype(np.float64))
    assert sent["prompt"] == "put the block on the plate"
    np.testing.assert_allclose(np.stack(actions[:4]), peer.actions()[:4], rtol=1e-6)
    assert actions[0].shape == (8,)


def test_keymap_libero_path_through_our_server():
    """LIBERO's processes are openpi clients of our server on loopback, which holds the candidate
    (here a server candidate with the LIBERO preset): our keys in, openpi's keys to the peer."""
    from r2s_eval.libero import STATE_DIM
    from r2s_eval.libero.rollout import policy_cameras

    cameras = {"image": "agentview", "image2": "robot0_eye_in_hand", "wrist_image": "robot0_eye_in_hand"}
    with PeerServer(OPENPI_LIBERO, action_dim=7) as peer:
        model = ServerPolicy("pi0_openpi", "127.0.0.1", peer.port, preset="openpi_libero", max_chunk=10)
        # Only the cameras the server's keys read are rendered.
        assert policy_cameras(model.spec, cameras, "pi0_openpi", model.key_map) == {
            IMG + "image": "agentview", IMG + "wrist_image": "robot0_eye_in_hand"}
        ours = PolicyServer(model)
        ours.start()
        try:
            client = WebsocketClientPolicy("127.0.0.1", ours.port)
            assert client.infer({"r2s_eval": "reset", "seed": 1}) == {"ok": True}
            obs = libero_observation()
            obs = {k: v for k, v in obs.items() if k != IMG + "image2"} | {STATE: obs[STATE][:STATE_DIM]}
            reply = client.infer(obs)
        finally:
            ours.stop()
            model.close()
    assert reply["actions"].shape == (10, 7)
    assert set(peer.requests[0]) == set(OPENPI_LIBERO)
    # A key map whose camera LIBERO does not feed stops before any episode, naming key and camera.
    bad = ServerPolicy("pi0_openpi", "127.0.0.1", 1, preset="openpi_libero", max_chunk=10,
                       keys={"observation/wrist_image": {"camera": "wrist"}})
    with pytest.raises(PolicyError, match=r"'pi0_openpi'.*'observation/wrist_image' reads camera 'wrist', "
                                          r"which LIBERO \(libero.observation.cameras\) does not offer"):
        policy_cameras(bad.spec, cameras, "pi0_openpi", bad.key_map)
    wide = ServerPolicy("pi0_openpi", "127.0.0.1", 1, preset="openpi_libero", max_chunk=10,
                        keys={"observation/state": {"state": [0, 9]}})
    with pytest.raises(PolicyError, match=r"'observation/state' reads state\[0:9\], beyond the 8-D state"):
        policy_cameras(wide.spec, cameras, "pi0_openpi", wide.key_map)


def test_keymap_strict_server_refuses_our_own_keys():
    """Without a map no openpi server can be evaluated: the strict peer says so, and our client
    names the policy and the server's complaint."""
    with PeerServer(OPENPI_LIBERO, action_dim=7) as peer:
        policy = ServerPolicy("plain", "127.0.0.1", peer.port, cameras=[IMG + "image"], action_dim=7,
                              max_chunk=10, uses_task=True)
        try:
            with pytest.raises(PolicyError, match=r"(?s)'plain' at 127.0.0.1:\d+: server error: .*unexpected keys"):
                policy.predict_chunks([0], [policy.select(libero_observation())])
        finally:
            policy.close()


def test_keymap_default_requests_are_byte_identical():
    """No map: the request is our own stream names, byte for byte as before key maps existed."""
    obs = panda_observation()
    with PeerServer(None, action_dim=8) as peer:
        policy = ServerPolicy("plain", "127.0.0.1", peer.port, cameras=[IMG + "front"], action_dim=8,
                              max_chunk=10, uses_task=True, state_dim=8)
        try:
            assert policy.key_map is None and "keys" not in policy.metadata()
            policy.predict_chunks([0], [policy.select(obs)])
        finally:
            policy.close()
    expected = pack({IMG + "front": obs[IMG + "front"], STATE: obs[STATE], "task": obs["task"]})
    assert peer.raw == [expected]


def test_keymap_overrides_drop_and_add_keys():
    obs = panda_observation()
    accepts = {"observation/image": ((96, 96, 3), np.uint8), "observation/state": ((7,), np.float32),
               "observation/head": ((128, 128, 3), np.uint8), "prompt": str}
    keys = {
        "observation/image": {"camera": "front", "size": [96, 96]},  # another camera and size; uint8 kept
        "observation/state": {"state": [0, 7], "dtype": "float32"},
        "observation/wrist_image": None,  # this server reads no wrist view
        "observation/head": {"camera": "head_left"},  # a key the preset lacks, as rendered
    }
    with PeerServer(accepts, action_dim=7) as peer:
        policy = ServerPolicy("custom", "127.0.0.1", peer.port, preset="openpi_libero", keys=keys, max_chunk=10)
        try:
            assert policy.spec.cameras == (IMG + "front", IMG + "head_left")
            assert policy.metadata()["keys"]["observation/image"] == {"camera": "front", "size": [96, 96], "dtype": "uint8"}
            policy.predict_chunks([0], [policy.select(obs)])
        finally:
            policy.close()
    np.testing.assert_array_equal(peer.requests[0]["observation/image"],
                                  image_tools.resize_with_pad(obs[IMG + "front"], 96, 96))
    assert list(peer.requests[0]) == ["observation/image", "observation/state", "prompt", "observation/head"]


def test_keymap_unfilled_key_fails_before_any_connection():
    # DROID's images need our camera names: nothing fills them, and nothing is contacted (port 1).
    with pytest.raises(PolicyError) as caught:
        ServerPolicy("droid_lab", "127.0.0.1", 1, preset="openpi_droid", max_chunk=10)
    message = str(caught.value)
    assert "'droid_lab'" in message
    for key in ("observation/exterior_image_1_left", "observation/wrist_image_left"):
        assert f"server key {key!r} ('preset': openpi_droid) is filled by nothing (camera missing)" in message
    # Half filled: only the other key is named.
    with pytest.raises(PolicyError, match=r"'observation/wrist_image_left'.*camera missing") as caught:
        ServerPolicy("droid_lab", "127.0.0.1", 1, preset="openpi_droid", max_chunk=10,
                     keys={"observation/exterior_image_1_left": {"camera": "front"}})
    assert "exterior" not in str(caught.value)
    # A key of its own with only a dtype is filled by nothing either.
    with pytest.raises(PolicyError, match=r"'mine': server key 'obs/extra' is filled by nothing \(stream missing\)"):
        resolve_key_map(None, {"obs/extra": {"dtype": "float32"}}, "policy 'mine'")


def test_keymap_streams_the_world_lacks_are_named_by_key():
    policy = ServerPolicy("droid_lab", "127.0.0.1", 1, preset="openpi_droid", max_chunk=10,
                          keys={**DROID_CAMERAS, "observation/exterior_image_1_left": {"camera": "exterior"}})
    obs = panda_observation()
    with pytest.raises(PolicyError, match=r"'droid_lab'.*'observation/exterior_image_1_left' reads camera 'exterior', "
                                          r"which the world does not offer \(cameras: \['front', 'head_left', 'wrist'\]\)"):
        policy.select(obs)
    narrow = {**obs, STATE: obs[STATE][:7]}  # a 7-D state: the gripper slice lies beyond it
    with pytest.raises(PolicyError, match=r"'observation/gripper_position' reads state\[7:8\], beyond the 7-D state"):
        policy.key_map.check_obs(narrow, "policy 'droid_lab'")
    # Before any episode, from what a world offers:
    with pytest.raises(PolicyError, match=r"'observation/exterior_image_1_left' reads camera 'exterior'"):
        policy.key_map.check_streams(["front", "wrist"], 8, "policy 'droid_lab'")
    policy.close()


@pytest.mark.parametrize("keys, match", [
    ({"prompt": {"instruction": True, "camera": "front"}}, r"names 2 streams \(camera and instruction\)"),
    ({"observation/state": {"state": [3, 3]}}, r"state must be true .* or \[start, stop\]"),
    ({"observation/state": {"dtype": "uint8"}}, r"the state travels as float32 or float64, not uint8"),
    ({"observation/image": {"dtype": "float32"}}, r"images travel as uint8, not float32"),
    ({"prompt": {"dtype": "float32"}}, r"the instruction travels as text"),
    ({"observation/state": {"size": [8, 8]}}, r"size is for images"),
    ({"observation/image": {"cam": "front"}}, r"unknown field\(s\) \['cam'\]"),
    ({"observation/depth": None}, r"null drops a preset key, and 'observation/depth' is not one of preset"),
    ({"r2s_eval": {"instruction": True}}, r"reset message"),
    ({"prompt": "task"}, r"'prompt' must map to its stream"),
])
def test_keymap_bad_entries_are_named(keys, match):
    with pytest.raises(PolicyError, match=r"^policy 'p'.*" + match):
        resolve_key_map("openpi_libero", keys, "policy 'p'")


def test_keymap_misc_contract():
    with pytest.raises(PolicyError, match=r"'preset' must be one of \['openpi_droid', 'openpi_libero'\]"):
        resolve_key_map("openpi_aloha", None, "policy 'p'")
    assert resolve_key_map(None, None, "policy 'p'") is None
    with pytest.raises(PolicyError, match="spec \\['cameras'\\] come from its key map"):
        ServerPolicy("p", "127.0.0.1", 1, preset="openpi_libero", cameras=[IMG + "image"])
    # The spec's action width wins over the preset's.
    assert ServerPolicy("p", "127.0.0.1", 1, preset="openpi_libero", action_dim=6, max_chunk=4).spec.action_dim == 6
    whole = resolve_key_map(None, {"s": {"state": True}}, "policy 'p'")
    assert whole.to_dict() == {"s": {"state": True}} and whole.min_state_dim == 0
    assert set(PRESETS) == {"openpi_libero", "openpi_droid"}


@pytest.mark.parametrize("shape", [(256, 256), (128, 160), (300, 120), (224, 224), (50, 51)])
def test_keymap_resize_matches_openpi_client(shape):
    img = np.random.default_rng(0).integers(0, 255, size=(*shape, 3), dtype=np.uint8)
    np.testing.assert_array_equal(resize_with_pad(img, 224, 224), image_tools.resize_with_pad(img, 224, 224))

"""Policies over the network, in the openpi websocket protocol (msgpack + numpy arrays).

    PolicyServer(policy, host="127.0.0.1", port=0, api_key=None)   # serve any ChunkPolicy
    ServerPolicy(name, host, port, api_key_env=None, ...)           # a served policy as a ChunkPolicy
    ServerPolicy(..., preset="openpi_libero", keys={...})           # ... that reads a peer's own keys
    pack(obj) -> bytes; unpack(bytes) -> obj                        # strict wire codec

`python -m r2s_eval.serve PATH` serves a LeRobot checkpoint.
"""

from r2s_eval.serving.client import ServerPolicy
from r2s_eval.serving.keymap import PRESETS, KeyMap, resolve_key_map
from r2s_eval.serving.protocol import ProtocolError, pack, unpack, unpack_dict
from r2s_eval.serving.policy_server import PolicyServer

__all__ = ["PRESETS", "KeyMap", "PolicyServer", "ProtocolError", "ServerPolicy", "pack", "resolve_key_map", "unpack",
           "unpack_dict"]

"""A policy served over the openpi websocket protocol, as a `ChunkPolicy`.

Works with our `PolicyServer` and with foreign openpi servers. Each episode slot has its own
connection, so a server that keeps per-connection state (ours does) keeps it per episode. A
connection lost mid-episode is an error, not a silent reconnect (the server's episode state is
gone); the slot's next `reset()` connects again.

Every failure is a `PolicyError` naming the policy and `host:port`. Like the other policies,
one caller at a time (not thread-safe).

Requests carry our own stream names unless the policy has a key map (`preset=` / `keys=`, see
`r2s_eval.serving.keymap`): then each of the server's keys is filled from the stream the map
names, at the map's image size and dtype, and the spec's cameras, state and instruction use are
the map's.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping, Sequence

import numpy as np
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus, InvalidURI
from websockets.sync.client import ClientConnection, connect

from r2s_eval.policies.interface import ChunkPolicy, PolicyError, PolicySpec
from r2s_eval.serving.keymap import KeyMap, resolve_key_map
from r2s_eval.serving.protocol import DEFAULT_MAX_MESSAGE_BYTES, ProtocolError, pack, unpack_dict
from r2s_eval.serving.policy_server import RESET_KEY, ws_url

log = logging.getLogger(__name__)


def _json_safe(value):
    # Foreign servers' metadata may hold arrays; metadata() must stay JSON-able (cache keys).
    if isinstance(value, dict):
        return {(k.decode() if isinstance(k, bytes) else str(k)): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    if isinstance(value, bytes):
        return value.hex()
    return value


class ServerPolicy(ChunkPolicy):
    def __init__(self, name: str, host: str, port: int, api_key_env: str | None = None,
                 connect_timeout_s: float = 10.0, reply_timeout_s: float = 60.0,
                 connect_retries: int = 3, backoff_s: float = 0.5, *,
                 cameras: Sequence[str] | None = None, action_dim: int | None = None,
                 max_chunk: int | None = None, uses_state: bool | None = None,
                 uses_task: bool | None = None, state_dim: int | None = None,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 preset: str | None = None, keys: Mapping | KeyMap | None = None):
        self.name = name
        self.host = host
        self.port = int(port)
        self.where = f"{host}:{port}"
        self.connect_timeout_s = connect_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self.connect_retries = int(connect_retries)
        self.backoff_s = backoff_s
        self.max_message_bytes = int(max_message_bytes)
        self._api_key = None
        if api_key_env is not None:
            self._api_key = os.environ.get(api_key_env)
            if not self._api_key:
                raise self._error(f"environment variable {api_key_env} (the API key) is not set")
        # Spec fields given here win over what the server announces (foreign servers announce none).
        given = {"cameras": cameras, "action_dim": action_dim, "max_chunk": max_chunk,
                 "uses_state": uses_state, "uses_task": uses_task, "state_dim": state_dim}
        # The server's own key names, when they are not ours (checked before any connection).
        self.key_map = keys if isinstance(keys, KeyMap) else resolve_key_map(preset, keys, f"policy {name!r}")
        if self.key_map is not None:
            clash = [k for k in ("cameras", "uses_state", "uses_task") if given[k] is not None]
            if clash:
                raise PolicyError(f"policy {name!r}: spec {clash} come from its key map ('keys' / 'preset'); "
                                  f"leave them out of the spec")
            given.update(cameras=self.key_map.cameras, uses_state=self.key_map.uses_state,
                         uses_task=self.key_map.uses_task)
            if action_dim is None:
                given["action_dim"] = self.key_map.action_dim
        self._spec_args = {k: v for k, v in given.items() if v is not None}
        self._spec: PolicySpec | None = None
        self._server_metadata: dict | None = None
        self._conns: dict[int, ClientConnection] = {}
        self._broken: dict[int, str] = {}  # slot -> why its episode cannot go on
        self._spare: ClientConnection | None = None  # opened to read the spec; given to a slot
        if {"cameras", "action_dim", "max_chunk"} <= self._spec_args.keys():
            self._spec = self._build_spec({})

    def __repr__(self) -> str:
        return f"ServerPolicy({self.name!r}, {self.where})"

    def _error(self, what: str, slot: int | None = None) -> PolicyError:
        exc = PolicyError(f"policy {self.name!r} at {self.where}: {what}")
        exc.slot = slot
        return exc

    # -- spec and metadata ---------------------------------------------------------------------
    def _build_spec(self, announced: dict) -> PolicySpec:
        fields = {**announced, **self._spec_args}
        missing = [k for k in ("cameras", "action_dim", "max_chunk") if k not in fields]
        if missing:
            raise self._error(f"the server announces no spec; give {missing} to ServerPolicy")
        try:
            spec = PolicySpec.from_dict({k: fields[k] for k in PolicySpec.__dataclass_fields__ if k in fields})
        except (TypeError, ValueError) as exc:
            raise self._error(f"bad spec {fields}: {exc}") from exc
        if spec.action_dim < 1 or spec.max_chunk < 1:
            raise self._error(f"bad spec {spec}")
        return spec

    @property
    def spec(self) -> PolicySpec:
        if self._spec is None:
            self._spare = self._spare or self._open()
        return self._spec

    @property
    def server_metadata(self) -> dict:
        if self._server_metadata is None:
            self._spare = self._spare or self._open()
        return self._server_metadata

    @property
    def supports_reset(self) -> bool:
        return self.server_metadata.get("supports_reset") is True

    def metadata(self) -> dict:
        # What the server serves, never where it runs: the same model on another host is the same policy.
        meta = self.server_metadata
        served = meta.get("policy") if "policy" in meta else meta
        out = {"name": self.name, "spec": self.spec.to_dict(), "served": _json_safe(served)}
        if self.key_map is not None:  # what the server is shown decides what it does
            out["keys"] = self.key_map.to_dict()
        return out

    def select(self, obs: dict) -> dict:
        if self.key_map is not None:  # a missing stream is named by the server key it fills
            self.key_map.check_obs(obs, f"policy {self.name!r}")
        return super().select(obs)

    def request(self, selected: dict) -> dict:
        """The message sent for a selected observation: ours as it is, or the key map's."""
        if self.key_map is None:
            return selected
        return self.key_map.request(selected)

    # -- connections ---------------------------------------------------------------------------
    def _connect_once(self) -> ClientConnection:
        headers = {"Authorization": f"Api-Key {self._api_key}"} if self._api_key else None
        connecting = connect(ws_url(self.host, self.port), open_timeout=self.connect_timeout_s,
                             close_timeout=min(self.connect_timeout_s, 5.0), max_size=self.max_message_bytes,
                             compression=None, additional_headers=headers)
        # Entering is how every websockets version hands out a long-lived connection without a
        # deprecation warning; `close()` ends it.
        return connecting.__enter__()

    def _open(self) -> ClientConnection:
        for attempt in range(self.connect_retries + 1):
            try:
                conn = self._connect_once()
                break
            except (ConnectionRefusedError, ConnectionResetError) as exc:
                # The server may still be starting: retry with growing pauses.
                if attempt == self.connect_retries:
                    raise self._error("connection refused (is the server running?)") from exc
                time.sleep(self.backoff_s * 2**attempt)
            except InvalidStatus as exc:
                status = exc.response.status_code
                hint = " (missing or wrong API key?)" if status in (401, 403) else ""
                raise self._error(f"server refused the connection: HTTP {status}{hint}") from exc
            except TimeoutError as exc:
                raise self._error(f"timed out connecting after {self.connect_timeout_s}s") from exc
            except (OSError, InvalidHandshake, InvalidURI) as exc:
                raise self._error(f"cannot connect: {exc}") from exc
        meta = self._receive(conn, self.connect_timeout_s, "the server metadata")
        try:
            self._check_metadata(meta)
        except PolicyError:
            conn.close()
            raise
        log.info("policy %r: connected to %s", self.name, self.where)
        return conn

    def _check_metadata(self, meta: dict) -> None:
        if self._server_metadata is None:
            spec = meta.get("spec")
            self._spec = self._spec or self._build_spec(spec if isinstance(spec, dict) else {})
            self._server_metadata = meta
            return
        # A server restarted with another model must not pass for the one already evaluated.
        before, now = (_json_safe(m.get("policy", m)) for m in (self._server_metadata, meta))
        if now != before:
            raise self._error(f"the server now serves {now}, not {before} as before")

    def _receive(self, conn: ClientConnection, timeout_s: float, what: str) -> dict:
        """One message from the server as a dict; closes `conn` on any failure."""
        try:
            reply = conn.recv(timeout=timeout_s)
            if isinstance(reply, str):
                raise self._error(f"server error: {reply}")
            return unpack_dict(reply, self.max_message_bytes)
        except TimeoutError as exc:
            conn.close()
            raise self._error(f"no reply within {timeout_s}s waiting for {what}") from exc
        except ConnectionClosed as exc:
            raise self._error(f"connection closed while waiting for {what} ({exc})") from exc
        except ProtocolError as exc:
            conn.close()
            raise self._error(f"bad message waiting for {what}: {exc}") from exc
        except PolicyError:
            conn.close()
            raise

    def _drop(self, slot: int, why: str) -> None:
        conn = self._conns.pop(slot, None)
        if conn is not None:
            conn.close()
        self._broken[slot] = why

    def _conn(self, slot: int) -> ClientConnection:
        if slot in self._broken:
            raise self._error(f"slot {slot}: {self._broken[slot]}; reset the slot to reconnect", slot)
        if slot not in self._conns:  # first use of the slot starts its episode
            self._conns[slot] = self._spare or self._open()
            self._spare = None
        return self._conns[slot]

    # -- ChunkPolicy -------------------------------------------------------------------------
    def reset(self, slot: int, seed: int) -> None:
        if slot in self._broken:
            self._broken.pop(slot)
            self._conns.pop(slot, None)
        conn = self._conn(slot)
        if not self.supports_reset:
            return
        try:
            conn.send(pack({RESET_KEY: "reset", "seed": int(seed)}))
            reply = self._receive(conn, self.reply_timeout_s, "the reset acknowledgement")
        except (PolicyError, ConnectionClosed) as exc:
            self._drop(slot, "reset failed")
            if isinstance(exc, PolicyError):
                raise
            raise self._error(f"connection closed while resetting slot {slot} ({exc})") from exc
        if reply.get("ok") is not True:
            self._drop(slot, "reset failed")
            raise self._error(f"server did not acknowledge the reset: {reply}")

    def predict_chunks(self, slots: Sequence[int], observations: Sequence[dict]) -> np.ndarray:
        if len(slots) != len(observations):
            raise self._error(f"{len(slots)} slots but {len(observations)} observations")
        payloads = [pack(self.request(self.select(obs))) for obs in observations]
        conns = [self._conn(slot) for slot in slots]
        pending: list[int] = []  # slots whose reply is still on the wire
        try:
            # Send every slot's observation before waiting: the server works while others travel.
            for slot, conn, payload in zip(slots, conns, payloads):
                pending.append(slot)
                try:
                    conn.send(payload)
                except ConnectionClosed as exc:
                    raise self._error(f"connection closed while sending the observation of slot {slot} ({exc})", slot) from exc
            chunks = []
            for slot, conn in zip(slots, conns):
                try:
                    chunks.append(self._actions(self._receive(conn, self.reply_timeout_s, f"the actions of slot {slot}")))
                except PolicyError as exc:
                    exc.slot = slot  # the episode whose reply failed
                    raise
                pending.remove(slot)
        except PolicyError:
            # An unread or failed reply leaves the connection out of step: those episodes end here.
            for slot in pending:
                self._drop(slot, "the connection failed mid-episode")
            raise
        horizon = min(len(c) for c in chunks)
        return np.stack([c[:horizon] for c in chunks])

    def _actions(self, reply: dict) -> np.ndarray:
        actions = reply.get("actions", reply.get(b"actions"))
        if not isinstance(actions, np.ndarray):
            raise self._error(f"reply has no 'actions' array (keys: {sorted(map(str, reply))})")
        dim = self.spec.action_dim
        if actions.ndim != 2 or actions.shape[0] < 1 or actions.shape[1] != dim:
            raise self._error(f"actions of shape {actions.shape}, expected (T>=1, {dim})")
        if actions.dtype.kind not in "iuf":
            raise self._error(f"actions of dtype {actions.dtype}, expected numbers")
        actions = actions.astype(np.float32)
        if not np.isfinite(actions).all():
            raise self._error("non-finite actions")
        return actions[: self.spec.max_chunk]

    def release(self, slot: int) -> None:
        """The slot's episode is over: its connection (one per episode) is closed."""
        conn = self._conns.pop(slot, None)
        if conn is not None:
            conn.close()
        self._broken.pop(slot, None)

    def close(self) -> None:
        for conn in [*self._conns.values(), *([self._spare] if self._spare else [])]:
            conn.close()
        self._conns.clear()
        self._broken.clear()
        self._spare = None

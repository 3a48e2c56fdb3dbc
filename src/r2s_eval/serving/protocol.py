"""The openpi wire format: msgpack with numpy arrays as tagged maps, decoded strictly.

Arrays travel as `{"__ndarray__": True, "data": bytes, "dtype": str, "shape": [...]}` and numpy
scalars as `{"__npgeneric__": True, "data": value, "dtype": str}`. openpi-client writes these tag
keys as msgpack *bytes*, so `pack` does too and `unpack` accepts str or bytes keys.

openpi-client's decoder trusts the message (an object dtype turns raw bytes into pointers); this
one only builds plain numeric arrays whose declared shape matches the bytes it was given, and
bounds message size and nesting depth. Everything rejected raises `ProtocolError`.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

from r2s_eval.errors import DataError

DEFAULT_MAX_MESSAGE_BYTES = 64 * 2**20
MAX_DEPTH = 32  # observations nest a few levels; anything deeper is malformed or hostile
MAX_NDIM = 32
ALLOWED_KINDS = "biuf"  # bool, signed and unsigned ints, floats: nothing holds pointers

_ND = "__ndarray__"
_NG = "__npgeneric__"


class ProtocolError(DataError):
    """A message that does not follow the protocol; the text says what was wrong."""


# -- encoding ---------------------------------------------------------------------------------


def _check_dtype_to_send(dtype: np.dtype) -> None:
    if dtype.kind not in ALLOWED_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise ProtocolError(f"cannot send arrays of dtype {dtype} (only bool, int, uint, float)")


def _encode(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        _check_dtype_to_send(obj.dtype)
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
    if isinstance(obj, np.generic):
        _check_dtype_to_send(obj.dtype)
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    raise ProtocolError(f"cannot send a {type(obj).__name__}")


def pack(obj: Any) -> bytes:
    """msgpack bytes that openpi-client (and `unpack`) decode back into `obj`."""
    try:
        return msgpack.packb(obj, default=_encode, use_bin_type=True)
    except ProtocolError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:
        raise ProtocolError(f"cannot encode message: {exc}") from exc


# -- decoding ---------------------------------------------------------------------------------


def _field(d: dict, name: str) -> Any:
    # Tag maps from openpi-client use bytes keys; ours accept either spelling.
    if name in d:
        return d[name]
    if name.encode() in d:
        return d[name.encode()]
    raise ProtocolError(f"array map lacks {name!r}")


def _dtype(value: Any) -> np.dtype:
    if isinstance(value, bytes):
        value = value.decode("ascii", errors="replace")
    if not isinstance(value, str) or len(value) > 8:
        raise ProtocolError(f"unknown dtype {value!r}")
    try:
        dtype = np.dtype(value)
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"unknown dtype {value!r}") from exc
    if dtype.kind not in ALLOWED_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise ProtocolError(f"dtype {value!r} not allowed (only bool, int, uint, float)")
    return dtype


def _array(d: dict) -> np.ndarray:
    dtype = _dtype(_field(d, "dtype"))
    data = _field(d, "data")
    shape = _field(d, "shape")
    if not isinstance(data, bytes):
        raise ProtocolError(f"array data must be bytes, got {type(data).__name__}")
    if not isinstance(shape, (list, tuple)) or len(shape) > MAX_NDIM:
        raise ProtocolError(f"array shape must be a list of at most {MAX_NDIM} sizes, got {shape!r}")
    if not all(type(n) is int and n >= 0 for n in shape):
        raise ProtocolError(f"array shape must hold non-negative ints, got {shape!r}")
    expected = math.prod(shape) * dtype.itemsize  # Python ints: no overflow
    if expected != len(data):
        raise ProtocolError(f"array of shape {tuple(shape)} and dtype {dtype} needs {expected} bytes, got {len(data)}")
    # A copy: writable, owns its memory, native byte order (torch.from_numpy needs that).
    return np.frombuffer(data, dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="), copy=True)


def _scalar(d: dict) -> np.generic:
    dtype = _dtype(_field(d, "dtype"))
    value = _field(d, "data")
    if type(value) not in (bool, int, float):
        raise ProtocolError(f"numpy scalar data must be a number, got {type(value).__name__}")
    try:
        return dtype.type(value)
    except (OverflowError, ValueError, TypeError) as exc:
        raise ProtocolError(f"numpy scalar {value!r} does not fit dtype {dtype}: {exc}") from exc


def _is_tagged(d: dict, tag: str) -> bool:
    return d.get(tag) is True or d.get(tag.encode()) is True


def _decode(obj: Any, depth: int) -> Any:
    if depth > MAX_DEPTH:
        raise ProtocolError(f"message nests deeper than {MAX_DEPTH} levels")
    if obj is None or type(obj) in (bool, int, float, str, bytes):
        return obj
    if isinstance(obj, list):
        return [_decode(v, depth + 1) for v in obj]
    if isinstance(obj, dict):
        if _is_tagged(obj, _ND):
            return _array(obj)
        if _is_tagged(obj, _NG):
            return _scalar(obj)
        return {k: _decode(v, depth + 1) for k, v in obj.items()}
    # msgpack extension types (timestamps, ExtType) are not part of the protocol.
    raise ProtocolError(f"unsupported value of type {type(obj).__name__}")


def unpack(data: bytes, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> Any:
    """Decode one message; arrays come back as writable numpy arrays."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ProtocolError(f"expected a binary message, got {type(data).__name__}")
    if len(data) > max_bytes:
        raise ProtocolError(f"message of {len(data)} bytes exceeds the limit of {max_bytes}")
    try:
        # Size checked above; unpackb caps every string, binary, array and map length at it too.
        raw = msgpack.unpackb(bytes(data), raw=False, use_list=True)
    except Exception as exc:  # msgpack raises ValueError, ExtraData, UnicodeDecodeError, ...
        raise ProtocolError(f"not a valid msgpack message: {type(exc).__name__}: {exc}") from exc
    return _decode(raw, 0)


def unpack_dict(data: bytes, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES) -> dict:
    """`unpack` for messages that must be maps (observations, replies, metadata)."""
    msg = unpack(data, max_bytes)
    if not isinstance(msg, dict):
        raise ProtocolError(f"expected a map, got {type(msg).__name__}")
    return msg

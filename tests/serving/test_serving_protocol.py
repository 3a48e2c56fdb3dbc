"""The wire codec: round trips, openpi-client interop both ways, strict rejection of bad arrays."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from openpi_client import msgpack_numpy

from r2s_eval.serving.protocol import MAX_DEPTH, ProtocolError, pack, unpack, unpack_dict


def _message() -> dict:
    rng = np.random.default_rng(0)
    return {
        "observation.state": rng.normal(size=14).astype(np.float32),
        "observation.images.head_left": rng.integers(0, 255, (8, 6, 3), dtype=np.uint8),
        "task": "pick the cube",
        "nested": {"ints": np.arange(6, dtype=np.int64).reshape(2, 3), "flags": np.array([True, False]),
                   "half": np.ones(3, np.float16), "u16": np.array([1, 65535], np.uint16),
                   "empty": np.zeros((0, 4), np.float64), "list": [1, 2.5, "x", None, b"raw"]},
        "scalar_f": np.float32(1.5),
        "scalar_i": np.int64(-7),
        "scalar_b": np.bool_(True),
        "plain": 3,
    }


def _assert_same(a, b):
    if isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    elif isinstance(a, np.generic):
        assert type(a) is type(b) and a == b
    elif isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _assert_same(x, y)
    else:
        assert a == b and type(a) is type(b)


def test_serving_protocol_round_trip():
    msg = _message()
    out = unpack(pack(msg))
    _assert_same(msg, out)
    assert out["observation.state"].flags.writeable  # a copy, not a view of the message


def test_serving_protocol_openpi_client_interop():
    msg = _message()
    # openpi-client -> us (its tag keys are bytes)
    _assert_same(msg, unpack(msgpack_numpy.packb(msg)))
    # us -> openpi-client
    _assert_same(msg, msgpack_numpy.unpackb(pack(msg)))
    # str tag keys, as other implementations write them
    arr = np.arange(4, dtype=np.float32)
    str_keys = msgpack.packb({"a": {"__ndarray__": True, "data": arr.tobytes(), "dtype": "<f4", "shape": [4]}})
    np.testing.assert_array_equal(unpack(str_keys)["a"], arr)
    # big-endian arrays arrive in native order
    be = unpack(pack({"a": arr.astype(">f4")}))["a"]
    assert be.dtype.isnative and np.array_equal(be, arr)


def _nd(dtype: str, shape, data: bytes) -> bytes:
    return msgpack.packb({"x": {b"__ndarray__": True, b"data": data, b"dtype": dtype, b"shape": shape}})


@pytest.mark.parametrize("dtype", ["|O", "O", "<U4", "|S4", "|V8", "<c8", "<M8[s]", "f4,i4", "(2,)f4", "xyz", "object_"])
def test_serving_protocol_rejects_unsafe_dtypes(dtype):
    with pytest.raises(ProtocolError, match="dtype"):
        unpack(_nd(dtype, [1], b"\0" * 8))


def test_serving_protocol_rejects_object_dtype_with_pointer_bytes():
    # openpi-client's decoder would read these bytes as an object pointer.
    with pytest.raises(ProtocolError, match="not allowed"):
        unpack(_nd("|O", [1], (0xDEADBEEF).to_bytes(8, "little")))
    with pytest.raises(ProtocolError, match="cannot send"):
        pack({"x": np.array([object()], dtype=object)})


@pytest.mark.parametrize("shape,data,match", [
    ([3], b"\0" * 8, "needs 12 bytes, got 8"),
    ([2, 2], b"\0" * 20, "needs 16 bytes, got 20"),
    ([-1], b"\0" * 4, "non-negative"),
    ([2**40, 2**40], b"\0" * 4, "needs"),
    ([1.5], b"\0" * 4, "non-negative ints"),
    ("4", b"\0" * 16, "shape"),
])
def test_serving_protocol_rejects_size_mismatch(shape, data, match):
    with pytest.raises(ProtocolError, match=match):
        unpack(_nd("<f4", shape, data))


def test_serving_protocol_rejects_malformed_messages():
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        unpack(pack({"img": np.zeros(2000, np.uint8)}), max_bytes=1000)
    with pytest.raises(ProtocolError, match="not a valid msgpack"):
        unpack(b"\xc1\x00\x01")
    with pytest.raises(ProtocolError, match="not a valid msgpack"):
        unpack(pack({"a": 1}) + b"trailing")
    with pytest.raises(ProtocolError, match="lacks 'data'"):
        unpack(msgpack.packb({"x": {"__ndarray__": True, "dtype": "<f4", "shape": [1]}}))
    with pytest.raises(ProtocolError, match="binary"):
        unpack("a text frame")
    deep = [1]
    for _ in range(MAX_DEPTH + 2):
        deep = [deep]
    with pytest.raises(ProtocolError, match="deeper"):
        unpack(msgpack.packb(deep))
    with pytest.raises(ProtocolError, match="unsupported"):
        unpack(msgpack.packb({"t": msgpack.ExtType(5, b"xx")}))
    with pytest.raises(ProtocolError, match="does not fit"):
        unpack(msgpack.packb({"s": {b"__npgeneric__": True, b"data": 300, b"dtype": "|u1"}}))
    with pytest.raises(ProtocolError, match="expected a map"):
        unpack_dict(pack([1, 2]))

"""mrdem_common.codec: numpy arrays through msgpack as ``[dtype, shape, bytes]`` and back."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mrdem_common.codec import (
    NDARRAY_EXT,
    CodecError,
    array_ext,
    array_from_ext,
    packb,
    plain,
    unpackb,
)

DTYPES = [
    "bool",
    "int8",
    "int16",
    "int32",
    "int64",
    "uint8",
    "uint16",
    "uint32",
    "uint64",
    "float16",
    "float32",
    "float64",
]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal dtype, shape and bytes (NaNs and signed zeros included)."""
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(0,), (5,), (0, 3), (3, 0, 2), (2, 3), (2, 3, 4)])
def test_arrays_of_every_accepted_dtype_and_shape_round_trip(dtype, shape):
    rng = np.random.default_rng(sum(shape) + len(dtype))
    array = (rng.normal(size=shape) * 100).astype(dtype)
    back = unpackb(packb({"a": array}))["a"]
    assert _same(back, array)
    assert back.flags.c_contiguous and back.flags.writeable and back.flags.owndata


@given(
    hnp.arrays(
        st.sampled_from(DTYPES).map(np.dtype),
        hnp.array_shapes(min_dims=1, max_dims=4, min_side=0, max_side=6),
    )
)
def test_any_array_round_trips_bit_for_bit(array):
    assert _same(unpackb(packb([array]))[0], array)


def test_the_payload_is_dtype_shape_and_row_major_bytes():
    """The wire format, read with plain msgpack (what a client in another language sees)."""
    array = np.arange(6, dtype=np.int32).reshape(2, 3)
    ext = msgpack.unpackb(packb(array), raw=False)
    assert isinstance(ext, msgpack.ExtType) and ext.code == NDARRAY_EXT == 1
    dtype, shape, data = msgpack.unpackb(ext.data, raw=False)
    assert (dtype, shape) == ("<i4", [2, 3])
    assert data == b"".join(int(v).to_bytes(4, "little") for v in range(6))


@pytest.mark.parametrize(
    "view",
    [
        lambda a: a[:, ::2],  # strided
        lambda a: a.T,  # transposed
        lambda a: np.asfortranarray(a),  # column-major
        lambda a: a[::-1, 1:],  # negative strides
    ],
)
def test_non_contiguous_arrays_travel_as_their_values(view):
    array = view(np.arange(20.0).reshape(4, 5))
    assert not array.flags.c_contiguous
    back = unpackb(packb(array))
    np.testing.assert_array_equal(back, array)
    assert back.flags.c_contiguous and back.dtype == array.dtype
    assert array_ext(array) == array_ext(np.ascontiguousarray(array))


def test_big_endian_arrays_are_sent_little_endian():
    array = np.arange(6, dtype=">f8").reshape(2, 3)
    back = unpackb(packb(array))
    assert back.dtype == np.dtype("<f8")
    np.testing.assert_array_equal(back, array)
    assert array_ext(array) == array_ext(array.astype("<f8"))


def test_a_0d_array_travels_as_shape_1():
    """As documented (np.ascontiguousarray has ndim >= 1; the wire format keeps that)."""
    back = unpackb(packb(np.array(2.5)))
    assert back.shape == (1,) and back[0] == 2.5


def test_numpy_scalars_travel_as_plain_numbers():
    payload = [np.float64(0.1), np.float32(1.5), np.int64(-3), np.uint8(7), np.bool_(True)]
    assert unpackb(packb(payload)) == [0.1, 1.5, -3, 7, True]
    assert packb(payload) == msgpack.packb([0.1, 1.5, -3, 7, True])
    assert [plain(v) for v in payload] == [0.1, 1.5, -3, 7, True]
    assert plain(np.arange(4).reshape(2, 2)) == [[0, 1], [2, 3]]


def test_other_python_objects_are_refused():
    with pytest.raises(TypeError, match="cannot encode object"):
        packb({"x": object()})
    with pytest.raises(TypeError, match="cannot encode complex"):
        plain(1j)


def _ext(dtype, shape, data, code=NDARRAY_EXT) -> bytes:
    return msgpack.packb(msgpack.ExtType(code, msgpack.packb([dtype, shape, data])))


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (_ext(">f8", [1], bytes(8)), "'>f8' not accepted"),
        (_ext("|O", [1], bytes(8)), "'|O' not accepted"),
        (_ext("<c16", [1], bytes(16)), "'<c16' not accepted"),
        (_ext("<f16", [1], bytes(16)), "not accepted"),
        (_ext("<f8", [2], bytes(8)), "needs 16 bytes, got 8"),
        (_ext("<f8", [-1], b""), "negative dimension"),
        (_ext("<f8", [1], "text"), "non-binary data"),
        (_ext("nope", [1], b"x"), "malformed msgpack array"),
        (msgpack.packb(msgpack.ExtType(NDARRAY_EXT, b"\xc1")), "malformed msgpack array"),
        (msgpack.packb(msgpack.ExtType(NDARRAY_EXT, msgpack.packb([1, 2]))), "malformed"),
    ],
)
def test_unreadable_arrays_say_what_is_wrong(body, message):
    for strict in (False, True):
        with pytest.raises(CodecError, match=message):
            unpackb(body, strict=strict)
    assert issubclass(CodecError, ValueError)


def test_other_extension_types_are_kept_or_refused_when_strict():
    body = msgpack.packb([msgpack.ExtType(5, b"abc")])
    assert unpackb(body) == [msgpack.ExtType(5, b"abc")]
    with pytest.raises(CodecError, match="unknown msgpack extension type 5"):
        unpackb(body, strict=True)


def test_array_from_ext_is_the_inverse_of_array_ext():
    array = np.linspace(0, 1, 12, dtype=np.float32).reshape(3, 4)
    ext = array_ext(array)
    assert ext.code == NDARRAY_EXT
    assert _same(array_from_ext(ext.data), array)


def test_map_keys_must_be_strings():
    with pytest.raises(ValueError, match="not allowed for map key"):
        unpackb(msgpack.packb({1: 2}))
